"""``jaxgeo simulate``: writes the scene files, refuses to overwrite them."""

import json

from jaxgeo.cli import main


def test_cartosat1_writes_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "pair"
    assert main(["simulate", "cartosat1", "--seed", "5", "--out", str(out)]) == 0
    files = sorted(p.name for p in out.iterdir())
    assert files == ["aft.txt", "fore.txt", "ground.csv", "observations.csv", "truth.json"]
    assert "vendor RPC direct georeferencing" in capsys.readouterr().out
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert main(["simulate", "cartosat1", "--seed", "6", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "refusing to overwrite" in err and "fore.txt" in err and "--overwrite" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main(["simulate", "cartosat1", "--seed", "6", "--out", str(out), "--overwrite"]) == 0
    assert (out / "fore.txt").read_bytes() != before["fore.txt"]
    assert json.loads((out / "truth.json").read_text())["params"]["seed"] == 6


def test_carto2s_strip(tmp_path, capsys):
    out = tmp_path / "strip"
    argv = ["simulate", "carto2s-strip", "--scenes", "2", "--seed", "1", "--out", str(out)]
    assert main([*argv, "--gcp-every", "1", "--quiet", "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""  # --quiet: no progress
    summary = json.loads(captured.out)  # --json: one object, what was written where
    assert summary["out"] == str(out) and summary["scenes"] == 2
    assert sorted(summary["files"]) == sorted(p.name for p in out.iterdir())
    assert 0 < summary["vendor_rms_px"]["min"] <= summary["vendor_rms_px"]["max"] < 100
    names = sorted(p.name for p in out.iterdir())
    assert names == ["ground.csv", "observations.csv", "scene_000.txt", "scene_001.txt",
                     "strip.json", "truth.json"]  # fmt: skip
    meta = json.loads((out / "strip.json").read_text())
    assert [s["first_line"] for s in meta["scenes"]] == [0, 46500]
    assert main(argv) == 2
    assert "refusing to overwrite" in capsys.readouterr().err


def test_bad_arguments(tmp_path, capsys):
    assert main(["simulate", "carto2s-strip", "--scenes", "0", "--out", str(tmp_path)]) == 2
    assert "--scenes must be >= 1" in capsys.readouterr().err
    for kind, option, value, message in (
        ("cartosat1", "--gcps", "-1", "--gcps must be >= 0"),
        ("cartosat1", "--noise-px", "-0.5", "--noise-px must be a finite number >= 0"),
        ("cartosat1", "--seed", "-2", "--seed must be >= 0"),
        ("carto2s-strip", "--gcp-every", "0", "--gcp-every must be >= 1"),
        ("stereo-scene", "--relief-m", "0", "--relief-m must be in (0, 2000]"),
    ):  # errors name the option, before any work: nothing written
        argv = ["simulate", kind, option, value, "--out", str(tmp_path / "x")]
        assert main([*argv, *(["--size", "64"] if kind == "stereo-scene" else [])]) == 2
        assert message in capsys.readouterr().err
        assert not (tmp_path / "x").exists()
    (tmp_path / "file").write_text("x")
    assert main(["simulate", "cartosat1", "--out", str(tmp_path / "file")]) == 2
    assert "not a directory" in capsys.readouterr().err


def test_stereo_scene_writes_refuses_and_names_bad_options(tmp_path, capsys):
    out = tmp_path / "scene"
    argv = ["simulate", "stereo-scene", "--size", "64", "--seed", "2", "--out", str(out)]
    assert main([*argv, "--exact-rpc", "--jitter-px", "0.5", "--quiet", "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""  # --quiet: no progress
    summary = json.loads(captured.out)
    assert sorted(summary["files"]) == sorted(p.name for p in out.iterdir())
    assert sorted(summary["files"]) == ["left.tif", "right.tif", "truth.json", "truth_dsm.tif"]
    assert max(summary["rpc_vs_truth_rms_px"].values()) < 0.05  # exact RPCs, jitter-free truth
    assert min(summary["rpc_vs_jittered_truth_rms_px"].values()) > 0.1  # the jitter they lack
    truth = json.loads((out / "truth.json").read_text())
    assert truth["params"]["jitter_px"] == 0.5 and truth["params"]["exact_rpc"] is True
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert main(argv) == 2  # checked before any work
    err = capsys.readouterr().err
    assert "refusing to overwrite" in err and "left.tif" in err and "--overwrite" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main(["simulate", "stereo-scene", "--size", "10", "-o", str(tmp_path / "x")]) == 2
    assert "--size must be an integer >= 64" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
