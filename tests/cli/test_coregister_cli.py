"""``jaxgeo coregister``: the JSON report, the human summary, the refusals (one line, exit 2,
the file named, nothing written)."""

import hashlib
import json

import numpy as np
import pytest
import rasterio
from affine import Affine

from jaxgeo.cli import build_parser, main
from tests.coreg.test_coregister import CELL_M, SHIFT, X0, Y0, shifted_pair, write_raster

STAT_KEYS = {"mean_m", "median_m", "nmad_m", "rmse_m", "le90_m", "cells", "std_m"}


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    folder = tmp_path_factory.mktemp("coregister")
    dsm, ref = shifted_pair(seed=7)
    return write_raster(folder / "dsm.tif", dsm), write_raster(folder / "ref.tif", ref)


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_json_report(pair, tmp_path, capsys):
    dsm, ref = pair
    out = tmp_path / "aligned.tif"
    assert main(["coregister", str(dsm), str(ref), "-o", str(out), "--json", "--quiet"]) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    assert captured.err == ""  # --quiet: no iteration lines
    assert {"shift_m", "before", "after", "iterations", "converged", "output", "dsm", "ref"} <= set(
        report
    )
    assert set(report["before"]) == STAT_KEYS and set(report["after"]) == STAT_KEYS
    assert len(report["shift_m"]) == 3 and report["converged"] is True
    assert np.all(np.abs(np.add(report["shift_m"], SHIFT)) < 0.3)  # what was added: -SHIFT
    assert report["after"]["nmad_m"] < report["before"]["nmad_m"]
    assert report["output"] == str(out) and out.is_file()
    with rasterio.open(out) as f:
        assert f.tags()["COREGISTRATION_SHIFT_M"].split()[0] == f"{report['shift_m'][0]:.4f}"


def test_human_summary_and_iteration_lines(pair, tmp_path, capsys):
    dsm, ref = pair
    out = tmp_path / "aligned.tif"
    assert main(["coregister", str(dsm), str(ref), "-o", str(out)]) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert lines[0].startswith("shift added to the DSM: dx -3.") and "converged" in lines[0]
    assert lines[2].startswith("before") and lines[3].startswith("after")
    assert lines[-1] == f"wrote {out}"
    assert captured.err.startswith("iteration 1: increment")


@pytest.mark.parametrize("which", ["dsm", "ref", "mask"])
def test_output_equal_to_an_input_is_refused_even_with_overwrite(pair, which, tmp_path, capsys):
    dsm, ref = pair
    mask = write_raster(tmp_path / "mask.tif", np.ones((8, 8)), nodata=None, dtype="uint8")
    target = {"dsm": dsm, "ref": ref, "mask": mask}[which]
    before = digest(target)
    argv = ["coregister", str(dsm), str(ref), "--mask", str(mask), "-o", str(target)]
    assert main([*argv, "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(target) in err and "input" in err
    assert digest(target) == before


def test_bad_inputs_one_line_exit_2(pair, tmp_path, capsys):
    dsm, ref = pair
    _, z = shifted_pair(seed=8)
    far = write_raster(tmp_path / "far.tif", z, Affine(CELL_M, 0, X0 + 5000, 0, -CELL_M, Y0))
    geo = write_raster(tmp_path / "geo.tif", z, Affine(1e-5, 0, 3.0, 0, -1e-5, 43.0), "EPSG:4326")
    (tmp_path / "exists.tif").write_bytes(b"")
    cases = [
        ([str(dsm), str(far)], "do not overlap", "far.tif"),
        ([str(geo), str(ref)], "geographic (degrees)", "geo.tif"),
        ([str(tmp_path / "none.tif"), str(ref)], "no such file", "none.tif"),
    ]
    for inputs, what, name in cases:
        out = tmp_path / "out.tif"
        assert main(["coregister", *inputs, "-o", str(out), "--quiet"]) == 2, what
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and what in err and name in err, err
        assert "Traceback" not in err and not out.exists()
    assert main(["coregister", str(dsm), str(ref), "-o", str(tmp_path / "exists.tif")]) == 2
    assert "exists" in capsys.readouterr().err


def test_help_lists_exit_codes():
    sub = build_parser("coregister")._subparsers._group_actions[0].choices["coregister"]
    epilog = sub.epilog
    for code in ("0", "1", "2", "130"):
        assert f"  {code}  " in epilog
    assert all(a.help for a in sub._actions)


def test_not_converged_exit_1_with_a_warning(pair, tmp_path, capsys):
    dsm, ref = pair
    out = tmp_path / "aligned.tif"
    argv = ["coregister", str(dsm), str(ref), "-o", str(out), "--quiet"]
    assert main([*argv, "--max-iterations", "1", "--tolerance", "1e-6"]) == 1
    captured = capsys.readouterr()
    assert "NOT converged" in captured.out and out.is_file()  # the last shift, written
    assert captured.err.startswith("jaxgeo coregister: warning: co-registration did not converge")


@pytest.mark.parametrize(
    "options, named",
    [
        (["--max-iterations", "0"], "--max-iterations 0: expected >= 1"),
        (["--tolerance", "-1"], "--tolerance -1.0: expected > 0"),
        (["--tolerance", "nan"], "--tolerance nan: expected > 0"),
        (["--nmad-k", "0"], "--nmad-k 0.0: expected > 0"),
        (["--min-slope", "80"], "--min-slope 80.0, --max-slope 70.0: expected 0 <= --min-slope"),
        (["--max-slope", "95"], "--max-slope 95.0: expected"),
        (["--geoid", "egm96", "--dem-height", "ellipsoidal"], "not with --dem-height ellipsoidal"),
    ],
)
def test_bad_values_are_named_by_their_options(pair, tmp_path, capsys, options, named):
    dsm, ref = pair
    out = tmp_path / "out.tif"
    assert main(["coregister", str(dsm), str(ref), "-o", str(out), *options]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxgeo coregister: error: ") and err.count("\n") == 1
    assert named in err, err
    for internal in ("max_iterations", "tolerance_m", "nmad_k", "slope_deg", "height="):
        assert internal not in err
    assert not out.exists()


def test_orthometric_reference_with_its_geoid(tmp_path, capsys):
    """``--geoid`` (or ``--dem-height orthometric``): REF's orthometric heights are made
    ellipsoidal, like the DSM's; without it the values are compared as they are (today's
    default), the undulation taken for a vertical shift."""
    from tests.coreg.test_coregister import GEOID, orthometric_pair

    undulation = orthometric_pair(tmp_path)
    dsm, ref, ortho = (str(tmp_path / n) for n in ("dsm.tif", "ref.tif", "ref_orthometric.tif"))

    def shift(*argv):
        out = tmp_path / "aligned.tif"
        assert main(["coregister", *argv, "-o", str(out), "--json", "--overwrite"]) == 0
        captured = capsys.readouterr()
        return np.array(json.loads(captured.out)["shift_m"]), captured.err

    truth, _ = shift(dsm, ref, "--quiet")
    converted, err = shift(dsm, ortho, "--geoid", str(GEOID))
    assert np.allclose(converted, truth, atol=0.01)
    assert f"REF {ortho.rsplit('/', 1)[1]}: orthometric heights + {GEOID.name}" in err
    as_is, _ = shift(dsm, ortho, "--quiet")
    assert abs(as_is[2] - truth[2] + undulation.mean()) < 0.1
    quiet, err = shift(dsm, ortho, "--geoid", str(GEOID), "--dem-height", "orthometric", "--quiet")
    assert np.allclose(quiet, converted, atol=1e-9) and err == ""
    assert main(["coregister", dsm, ortho, "-o", str(tmp_path / "x.tif"), "--dem-height",
                 "orthometric"]) == 2  # fmt: skip
    assert "orthometric heights need a geoid" in capsys.readouterr().err


def test_a_declared_vertical_crs_used_as_read_names_the_options(tmp_path, capsys):
    from tests.coreg.test_coregister import orthometric_pair

    orthometric_pair(tmp_path)
    with rasterio.open(tmp_path / "ref_orthometric.tif") as f:
        z = f.read(1)
    ref = write_raster(tmp_path / "ref_egm96.tif", z, crs="EPSG:32631+5773")
    out = tmp_path / "aligned.tif"
    assert main(["coregister", str(tmp_path / "dsm.tif"), str(ref), "-o", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("jaxgeo coregister: warning: ") and err.count("\n") == 1
    assert "'EGM96 height'" in err and "(--dem-height, --geoid)" in err and "read_dem" not in err


def test_diff_written_with_its_statistics(pair, tmp_path, capsys):
    """``--diff DH``: the height difference after the alignment, its statistics in the JSON,
    the summary and the file's tags; an input as DH refused (exit 2, nothing written)."""
    dsm, ref = pair
    out, dh = tmp_path / "aligned.tif", tmp_path / "dh.tif"
    argv = ["coregister", str(dsm), str(ref), "-o", str(out), "--diff", str(dh), "--quiet"]
    assert main([*argv, "--json"]) == 0
    report = json.loads(capsys.readouterr().out)["diff"]
    assert report["output"] == str(dh) and report["grid_step"] == 1
    assert set(report["before"]) == STAT_KEYS == set(report["after"])
    assert abs(report["after"]["median_m"]) < 0.05 < report["before"]["nmad_m"] - 1.0
    with rasterio.open(dh) as f:
        assert float(f.tags()["DH_AFTER_NMAD_M"]) == pytest.approx(report["after"]["nmad_m"],
                                                                   abs=1e-4)  # fmt: skip
    assert main([*argv, "--overwrite"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[4].startswith("height difference DSM - REF over every cell")
    assert lines[6].startswith("before") and lines[7].startswith("after")
    assert lines[-2:] == [f"wrote {dh}", f"wrote {out}"]
    before = digest(ref)
    assert main(["coregister", str(dsm), str(ref), "-o", str(tmp_path / "o2.tif"), "--diff",
                 str(ref), "--overwrite"]) == 2  # fmt: skip
    assert "input" in capsys.readouterr().err and digest(ref) == before
