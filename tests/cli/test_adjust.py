"""``jaxgeo adjust`` and ``jaxgeo demo`` on the embedded Cartosat-1 scene."""

import json
import shutil

import numpy as np
import pytest

from jaxgeo.cli import main
from jaxgeo.io import read_rpc
from jaxgeo.simulate import demo_dir


@pytest.fixture()
def scene(tmp_path):
    d = tmp_path / "in"
    shutil.copytree(demo_dir(), d)
    return d


def _args(d, *extra):
    return [
        "adjust",
        "--image",
        f"fore={d / 'fore.txt'}",
        "--image",
        f"aft={d / 'aft.txt'}",
        "--ground",
        str(d / "ground.csv"),
        "--observations",
        str(d / "observations.csv"),
        *extra,
    ]


def test_adjust_json_and_outputs(scene, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(_args(scene, "--bias", "shift", "--json", "--out", str(out))) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["converged"] and 0.3 < data["s0"] < 1.0
    chk = data["checkpoints"]
    assert chk["n"] == 60 and len(chk["rms_m"]) == 3
    assert max(chk["rms_m"][:2]) < 1.25 and chk["rms_m"][2] < 2.5
    assert all(lo <= hi for lo, hi in zip(chk["min_m"], chk["max_m"], strict=True))
    for name in ("fore", "aft"):
        assert max(data["images"][name]["rms_px"]) < 0.6
        assert set(data["images"][name]["params"]) == {".bias.shift_px[0]", ".bias.shift_px[1]"}
    assert data["direct"]["checkpoints"]["rms_m"][1] > 30.0  # before: tens of metres
    names = {p.split("/")[-1] for p in data["written"]}
    assert names == {
        "fore_RPC.TXT",  # <image stem>_RPC.TXT: where GDAL looks for fore.tif's RPC
        "aft_RPC.TXT",
        "adjusted_models.json",
        "ground_adjusted.csv",
        "residuals.csv",
        "report.json",
        "report.txt",
    }
    # the shift folds exactly into the RPC: the written file reproduces the adjusted model
    models = json.loads((out / "adjusted_models.json").read_text())["images"]
    shift = np.array([models["fore"]["parameters"][f".bias.shift_px[{i}]"] for i in (0, 1)])
    vendor = read_rpc(scene / "fore.txt")
    assert data["rpc_files"]["fore"]["how"] == "exact"
    folded = read_rpc(out / "fore_RPC.TXT")
    g = np.asarray(vendor.ground_offset)
    np.testing.assert_allclose(
        np.asarray(folded.project(g)), np.asarray(vendor.project(g)) - shift, atol=1e-6
    )
    # the biases' joint covariance, what `jaxgeo dsm --orientation` propagates: its diagonal
    # the sigmas written per image, and the shifts of the two images correlated (shared GCPs)
    joint = json.loads((out / "adjusted_models.json").read_text())["covariance"]
    cov = np.asarray(joint["matrix"])
    for i, name in enumerate(joint["parameters"]):
        image, leaf = name.split(".", 1)
        assert np.isclose(np.sqrt(cov[i, i]), models[image]["sigmas"]["." + leaf], rtol=1e-9)
    sx = [joint["parameters"].index(f"{n}.bias.shift_px[0]") for n in ("fore", "aft")]
    assert abs(cov[sx[0], sx[1]]) > 0.1 * np.sqrt(cov[sx[0], sx[0]] * cov[sx[1], sx[1]])
    from jaxgeo.stereo._uncertainty import orientation_covariances

    np.testing.assert_allclose(
        orientation_covariances(out / "adjusted_models.json", ["fore", "aft"]),
        cov[np.ix_(*[[joint["parameters"].index(f"{n}.bias.shift_px[{k}]")
                      for n in ("fore", "aft") for k in (0, 1)]] * 2)],
    )  # fmt: skip
    # never over existing outputs, never over the inputs
    assert main(_args(scene, "--bias", "shift", "--out", str(out))) == 2
    assert "exists" in capsys.readouterr().err
    clash = out / "residuals.csv"  # an input named like an output: not even --overwrite
    shutil.copy(scene / "observations.csv", clash)
    args = _args(scene, "--bias", "shift", "--out", str(out), "--overwrite")
    args[args.index("--observations") + 1] = str(clash)
    assert main(args) == 2
    assert "over an input" in capsys.readouterr().err
    assert clash.read_text() == (scene / "observations.csv").read_text()


def test_adjust_table_and_errors(scene, capsys):
    # vendor RPCs with no bias adjusted leave s0 ~ 4: a converged solve with a poor fit exits 3
    # (documented in --help) and the warning says so
    assert main(_args(scene, "--bias", "none")) == 3
    captured = capsys.readouterr()
    assert "s0" in captured.err
    text = captured.out
    assert "RMS_x [pixel]" in text and "s0" in text and "direct" in text
    bad = [
        "adjust",
        "--image",
        f"fore={scene / 'fore.txt'}",
        "--ground",
        str(scene / "ground.csv"),
        "--observations",
        str(scene / "observations.csv"),
    ]
    assert main(bad) == 2
    assert "unknown image 'aft'" in capsys.readouterr().err
    assert main(["adjust", "--image", "fore", "--observations", "x.csv"]) == 2
    assert "NAME=FILE" in capsys.readouterr().err


def test_demo_compares_direct_and_adjusted(capsys):
    assert main(["demo", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["direct"]["checkpoints"]["rms_m"][1] > 30.0
    assert max(data["checkpoints"]["rms_m"][:2]) < 1.25


def test_adjust_writes_rpcs_gdal_finds(scene, tmp_path, capsys):
    """Images given as GeoTIFFs: ``--copy-images --rpc-format rpb`` puts each adjusted RPC
    (a shift-drift bias: refitted, error reported) beside a copy of its image, where GDAL reads
    it; ``--write-into`` puts it into the copy's tags; the inputs stay as they were."""
    import rasterio

    from jaxgeo.io import from_rasterio_rpc, write_geotiff_rpc

    for name in ("fore", "aft"):
        # sparse placeholders of the images' size (the measurements must lie inside them)
        write_geotiff_rpc(read_rpc(scene / f"{name}.txt"), scene / f"{name}.tif")
    args = _args(scene, "--bias", "shift-drift", "--json", "--copy-images", "--rpc-format", "rpb")
    args = [a.replace(".txt", ".tif") for a in args]
    out = tmp_path / "out"
    assert main([*args, "--out", str(out)]) == 0
    data = json.loads(capsys.readouterr().out)
    for name in ("fore", "aft"):
        info = data["rpc_files"][name]
        assert info["how"] == "refit" and info["max_error_px"] < 0.01
        assert {p.split("/")[-1] for p in info["files"]} == {f"{name}.RPB", f"{name}.tif"}
        with rasterio.open(out / f"{name}.tif") as src:
            gdal = from_rasterio_rpc(src.rpcs)
        mine = read_rpc(out / f"{name}.RPB")
        assert np.allclose(np.asarray(gdal.num), np.asarray(mine.num), rtol=1e-12)
        assert read_rpc(out / f"{name}.tif").image_offset[0] == mine.image_offset[0]
        original = read_rpc(scene / f"{name}.txt")
        assert read_rpc(scene / f"{name}.tif").image_offset[0] == original.image_offset[0]
    out2 = tmp_path / "into"
    assert main([*args[:-2], "--write-into", "--out", str(out2)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert {p.split("/")[-1] for p in data["rpc_files"]["fore"]["files"]} == {"fore.tif"}
    assert not list(out2.glob("*.RPB"))


def test_images_named_by_their_file_stem_as_in_every_command(scene, capsys):
    """``jaxgeo adjust IMG ...`` names each image by its file stem (as ``jaxgeo match`` writes
    them), the same adjustment as ``--image NAME=FILE``; a stem given twice, or no image at all,
    is refused naming the option."""
    tables = ["--ground", str(scene / "ground.csv"), "--observations",
              str(scene / "observations.csv"), "--bias", "shift", "--json"]  # fmt: skip
    assert main(_args(scene, "--bias", "shift", "--json")) == 0
    named = json.loads(capsys.readouterr().out)
    assert main(["adjust", str(scene / "fore.txt"), str(scene / "aft.txt"), *tables]) == 0
    positional = json.loads(capsys.readouterr().out)
    assert positional["s0"] == named["s0"] and positional["images"] == named["images"]
    # one positional, one named otherwise than its stem (a copy of aft's model)
    shutil.copy(scene / "aft.txt", scene / "aft_copy.txt")
    mixed = ["adjust", str(scene / "fore.txt"), "--image", f"aft={scene / 'aft_copy.txt'}"]
    assert main([*mixed, *tables]) == 0
    assert json.loads(capsys.readouterr().out)["s0"] == named["s0"]
    twice = ["adjust", str(scene / "fore.txt"), "--image", f"fore={scene / 'aft.txt'}"]
    assert main([*twice, *tables]) == 2
    assert "image 'fore' given twice" in capsys.readouterr().err
    assert main(["adjust", *tables]) == 2
    assert "give the images" in capsys.readouterr().err
