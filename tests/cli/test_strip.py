"""``jaxgeo strip`` on a small simulated Carto-2S strip: report, JSON, updated RPCs, errors."""

import contextlib
import io
import json
import pathlib
import shutil

import numpy as np
import pytest
import rasterio
from affine import Affine as GeoTransform

from jaxgeo.cli import main
from jaxgeo.io import read_ground, read_observations, read_rpc, write_observations
from jaxgeo.models import AffineBias, Biased
from jaxgeo.simulate import carto2s_strip
from jaxgeo.strip._universal import UniversalCorrection, UniversallyCorrected

NAMES = [f"scene_{k:03d}" for k in range(6)]  # GCPs in scenes 0, 4, 5
FAST = ["--rpc-grid", "9", "9", "5"]


@pytest.fixture(scope="module")
def strip_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("strip6")
    carto2s_strip(6, seed=2).save(d)
    return d


@pytest.fixture(scope="module")
def adjusted(strip_dir, tmp_path_factory):
    """One run with --out: ``(exit code, stdout, stderr, out dir)``."""
    out = tmp_path_factory.mktemp("adjusted") / "out"
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        rc = main(["strip", str(strip_dir), "--out", str(out), *FAST])
    return rc, stdout.getvalue(), stderr.getvalue(), out


def test_report_table(adjusted):
    rc, text, err, out = adjusted
    assert rc == 0, err
    lines = text.splitlines()
    for name in NAMES:
        assert any(line.startswith(name) for line in lines), name
    for a, b in zip(NAMES, NAMES[1:], strict=False):
        assert any(line.startswith(f"{a} | {b}") for line in lines)
    for stage in ("direct", "level1", "level2"):
        assert any(line.startswith(f"whole strip, {stage}") for line in lines)
    assert "converged" in text and "universal correction" in text
    assert f"wrote 8 files to {out}" in text


def test_report_json_and_accuracy(adjusted):
    _, _, _, out = adjusted
    data = json.loads((out / "report.json").read_text())
    s = data["report"]["strip"]
    direct, level2 = s["check_rms_m"]["direct"]["plan"], s["check_rms_m"]["level2"]["plan"]
    level1 = s["check_rms_m"]["level1"]["plan"]
    assert direct > 10.0 and max(level1, level2) < 1.0 and level2 < direct / 20
    assert s["tie_gap_m"]["level2"]["max"] < 0.05 < s["tie_gap_m"]["direct"]["rms"]
    assert [r["name"] for r in data["report"]["scenes"]] == NAMES
    assert set(data["models"]) == set(NAMES)
    assert len(data["correction"]["dlat_deg"]) == 6
    assert all(m["rpc_refit_px"]["check_max"] < 0.01 for m in data["models"].values())
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"{n}_RPC.TXT" for n in NAMES] + ["report.json", "report.txt"]
    )


def test_updated_rpcs_reproduce_final_models(strip_dir, adjusted):
    """The written RPCs equal the final models rebuilt from report.json (vendor RPC, level-1
    affine bias, universal correction) to < 0.01 px at the check points."""
    _, _, _, out = adjusted
    data = json.loads((out / "report.json").read_text())
    c = data["correction"]
    corr = UniversalCorrection(
        np.array([c["dlat_deg"], c["dlon_deg"]]),
        np.array(c["offset_latlon_deg"]),
        np.array(c["scale_latlon_deg"]),
    )
    ground = read_ground(strip_dir / "ground.csv")
    obs = read_observations(strip_dir / "observations.csv")
    index = {p: i for i, p in enumerate(ground.ids)}
    n_checked = 0
    for name in NAMES:
        b = data["models"][name]["bias"]
        bias = AffineBias(
            [b[".bias.shift_px[0]"], b[".bias.shift_px[1]"]],
            [[b[f".bias.matrix[{i},{j}]"] for j in (0, 1)] for i in (0, 1)],
        )
        final = UniversallyCorrected(Biased(read_rpc(strip_dir / f"{name}.txt"), bias), corr)
        seen = [p for p, img in zip(obs.point_ids, obs.images, strict=True) if img == name]
        g = np.array([ground.lonlath[index[p]] for p in seen if ground.role[index[p]] == "check"])
        rpc = read_rpc(out / f"{name}_RPC.TXT")
        err = np.asarray(rpc.project(g)) - np.asarray(final.project(g))
        assert np.abs(err).max() < 0.01, name
        n_checked += len(g)
    assert n_checked >= 5


def test_json_and_refusals(strip_dir, adjusted, tmp_path, capsys):
    _, _, _, out = adjusted
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    # existing outputs: refused before any work, nothing touched
    assert main(["strip", str(strip_dir), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "refusing to overwrite" in err and "--overwrite" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main(["strip", str(strip_dir), "--ties-per-pair", "0"]) == 2
    assert "--ties-per-pair must be >= 1" in capsys.readouterr().err
    assert main(["strip", str(strip_dir / "strip.json"), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["report"]["strip"]["converged"] and "written" not in data
    assert [r["name"] for r in data["report"]["scenes"]] == NAMES
    geom = tmp_path / "geom"  # OSSIM .geom (OTB, shareloc/CARS)
    assert main(["strip", str(strip_dir), "--json", "--out", str(geom), "--rpc-format", "geom",
                 *FAST]) == 0  # fmt: skip
    data = json.loads(capsys.readouterr().out)
    assert sorted(pathlib.Path(p).name for p in data["written"]) == sorted(
        [f"{n}.geom" for n in NAMES] + ["report.json", "report.txt"]
    )
    g = read_ground(strip_dir / "ground.csv").lonlath[:3]
    a, b = read_rpc(geom / "scene_001.geom"), read_rpc(out / "scene_001_RPC.TXT")
    np.testing.assert_allclose(np.asarray(a.project(g)), np.asarray(b.project(g)), atol=1e-3)


def test_output_over_input_refused(strip_dir, tmp_path, capsys):
    d = tmp_path / "s"
    shutil.copytree(strip_dir, d)
    meta = json.loads((d / "strip.json").read_text())
    meta["scenes"][0]["rpc"] = "out/scene_000_RPC.TXT"  # an input where an output would go
    (d / "out").mkdir()
    shutil.move(d / "scene_000.txt", d / "out" / "scene_000_RPC.TXT")
    (d / "strip.json").write_text(json.dumps(meta))
    before = (d / "out" / "scene_000_RPC.TXT").read_text()
    assert main(["strip", str(d), "--out", str(d / "out"), "--overwrite"]) == 2
    assert "over an input" in capsys.readouterr().err
    assert (d / "out" / "scene_000_RPC.TXT").read_text() == before


def test_bad_strips(strip_dir, tmp_path, capsys):
    d = tmp_path / "s"
    shutil.copytree(strip_dir, d)
    assert main(["strip", str(tmp_path / "nowhere")]) == 2
    assert "nowhere: no such strip description" in capsys.readouterr().err
    good = (d / "strip.json").read_text()
    (d / "strip.json").write_text(good[:-20])
    assert main(["strip", str(d)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxgeo strip: error: ") and "strip.json" in err and "JSON" in err
    assert len(err.strip().splitlines()) == 1
    (d / "strip.json").write_text(good)
    (d / "scene_003.txt").unlink()
    assert main(["strip", str(d)]) == 2
    err = capsys.readouterr().err
    assert "'scene_003'" in err and "scene_003.txt" in err and "not found" in err
    shutil.copy(strip_dir / "scene_003.txt", d)
    (d / "scene_002.txt").write_text("LINE_OFF: 12\n")  # truncated RPC
    assert main(["strip", str(d)]) == 2
    assert "scene_002.txt" in capsys.readouterr().err
    shutil.copy(strip_dir / "scene_002.txt", d)
    obs = (d / "observations.csv").read_text().replace("scene_001", "scene_101")
    (d / "observations.csv").write_text(obs)
    assert main(["strip", str(d)]) == 2
    assert "scene_101" in capsys.readouterr().err
    shutil.copy(strip_dir / "observations.csv", d)
    # two GCPs only: the distribution warning, then the correction cannot be determined
    lines = (d / "ground.csv").read_text().splitlines()
    gcps = [i for i, line in enumerate(lines) if ",gcp" in line]
    for i in gcps[2:]:
        lines[i] = lines[i].replace(",gcp", ",check")
    (d / "ground.csv").write_text("\n".join(lines) + "\n")
    assert main(["strip", str(d)]) == 2
    err = capsys.readouterr().err
    assert "warning: GCP distribution" in err and "--degree affine" in err
    assert "ground.csv: the quadratic universal correction needs at least 6 GCPs" in err
    assert "Traceback" not in err


def test_ties_only_needs_priors(strip_dir, capsys):
    assert main(["strip", str(strip_dir), "--ties-only-level1"]) == 2
    err = capsys.readouterr().err
    assert "--bias-prior-shift-px and --bias-prior-matrix" in err


def _dem(path, lon, lat, h_m):
    """A constant-height geographic GeoTIFF over ``lon`` x ``lat`` (ranges, degrees)."""
    step = 0.01
    cols, rows = (int(np.ceil((r[1] - r[0]) / step)) for r in (lon, lat))
    transform = GeoTransform(step, 0, lon[0], 0, -step, lat[1])
    with rasterio.open(path, "w", driver="GTiff", height=rows, width=cols, count=1,
                       dtype="float32", crs="EPSG:4326", nodata=-9999.0,
                       transform=transform) as dst:  # fmt: skip
        dst.write(np.full((rows, cols), h_m, dtype="float32"), 1)
    return path


def test_dem_tie_heights(strip_dir, adjusted, tmp_path, capsys):
    rpcs = [read_rpc(strip_dir / f"{n}.txt") for n in NAMES]
    lo = np.min([np.asarray(r.ground_offset - r.ground_scale) for r in rpcs], axis=0)
    hi = np.max([np.asarray(r.ground_offset + r.ground_scale) for r in rpcs], axis=0)
    h = float(np.mean(read_ground(strip_dir / "ground.csv").lonlath[:, 2]))
    dem = _dem(tmp_path / "dem.tif", (lo[0], hi[0]), (lo[1], hi[1]), h)
    argv = ["strip", str(strip_dir), "--dem", str(dem), "--tie-height-sigma-m", "50", "--json"]
    assert main(argv) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["report"]["strip"]["check_rms_m"]["level2"]["plan"] < 1.0
    assert data["options"]["tie_height_sigma_m"] == 50.0
    # the DEM vocabulary of every command (--dem-height, --geoid), --dem-offset-m added after
    argv = ["strip", str(strip_dir), "--dem", str(dem), "--dem-height", "ellipsoidal",
            "--dem-offset-m", "2", "--tie-height-sigma-m", "50", "--json", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    assert (
        json.loads(capsys.readouterr().out)["report"]["strip"]["check_rms_m"]["level2"]["plan"]
        < 1.0
    )
    for extra, words in ((["--geoid", "egm96"], "--geoid applies to a DEM"),
                         (["--tie-height", "100", "--dem", str(dem)], "--tie-height and --dem"),
                         (["--loss-scale", "-1"], "--loss-scale must be a positive number"),
                         (["--max-steps", "0"], "--max-steps must be at least 1")):  # fmt: skip
        assert main(["strip", str(strip_dir), *extra]) == 2
        err = capsys.readouterr().err
        assert words in err and "loss_scale" not in err and "max_steps" not in err, err
    mid = 0.5 * (lo[1] + hi[1])  # covers the first half of the strip only
    short = _dem(tmp_path / "short.tif", (lo[0], hi[0]), (mid, hi[1]), h)
    assert main(["strip", str(strip_dir), "--dem", str(short)]) == 2
    err = capsys.readouterr().err
    assert f"{short}: " in err and "points lie outside the DEM" in err


def test_gross_error_named_and_removed(strip_dir, adjusted, tmp_path, capsys):
    """A GCP measurement 60 px off: listed (point, sub-scene, w) and removed by default, flagged
    only with --keep-blunders; the clean run flags nothing. The options mirror jaxgeo adjust."""
    assert "gross errors: none flagged" in adjusted[1]
    from jaxgeo.cli import build_parser
    from jaxgeo.cli._strip import strip_config

    args = build_parser("strip").parse_args(
        ["strip", str(strip_dir), "--loss", "huber", "--loss-scale", "2", "--keep-blunders"]
    )
    solver = strip_config(args)[0].solver
    assert (solver.loss, solver.loss_scale, solver.remove_blunders) == ("huber", 2.0, False)
    d = tmp_path / "s"
    shutil.copytree(strip_dir, d)
    obs = read_observations(d / "observations.csv")
    ground = read_ground(d / "ground.csv")
    role = dict(zip(ground.ids, ground.role, strict=True))
    i = next(k for k, p in enumerate(obs.point_ids) if role[p] == "gcp")
    xy = obs.xy.copy()
    xy[i] += [36.0, -48.0]
    bad = type(obs)(obs.point_ids, obs.images, xy, obs.sigma_px)
    write_observations(bad, d / "observations.csv", overwrite=True)
    for extra, removed in (([], True), (["--keep-blunders"], False)):
        assert main(["strip", str(d), "--json", *extra]) == 0
        gross = json.loads(capsys.readouterr().out)["report"]["strip"]["gross_errors"]
        worst = max((f for f in gross["flagged"] if f["what"] == "image"), key=lambda f: f["w"])
        assert (worst["id"], worst["image"], worst["level"]) == (obs.point_ids[i], obs.images[i], 1)
        assert worst["w"] > 10 and worst["removed"] is removed
        assert gross["n_removed"] == (1 if removed else 0)
    assert main(["strip", str(d)]) == 0
    text = capsys.readouterr().out
    assert f"level 1: {obs.point_ids[i]}@{obs.images[i]}" in text and "removed" in text


def test_cli_conventions(strip_dir, tmp_path, capsys, monkeypatch):
    """Issue 27: -o/--out, --quiet, --json, exit codes in --help, progress on stderr, the
    report printed before a failed write (exit 4)."""
    with pytest.raises(SystemExit):
        main(["strip", "--help"])
    text = capsys.readouterr().out
    assert "exit status:" in text and all(f"\n    {k}  " in text for k in (0, 1, 2, 3, 4))
    assert "-o DIR, --out DIR" in text and "--quiet" in text
    out = tmp_path / "o"
    assert main(["strip", str(strip_dir), "-o", str(out), *FAST]) == 0
    err = capsys.readouterr().err
    for stage in ("adjusting 6 sub-scenes", "refitting 6 RPCs and writing"):
        assert f"jaxgeo strip: {stage}" in err, err
    assert main(["strip", str(strip_dir), "--quiet", "--json"]) == 0
    cap = capsys.readouterr()
    assert "jaxgeo strip: adjusting" not in cap.err and json.loads(cap.out)["exit_status"] == 0

    import jaxgeo.strip._files

    def fail(*args, **kwargs):
        raise PermissionError("disk says no")

    monkeypatch.setattr(jaxgeo.strip._files, "write_strip_outputs", fail)
    assert main(["strip", str(strip_dir), "-o", str(tmp_path / "o2"), "--quiet", *FAST]) == 4
    cap = capsys.readouterr()
    assert "whole strip, level2" in cap.out and "writing -o/--out failed: disk says no" in cap.err
