"""``jaxgeo adjust`` on messy input: a GCP 1 km off is named; --out checked before computing;
exit codes documented in --help."""

import csv
import os
import shutil

import pytest

from jaxgeo.cli import main
from jaxgeo.simulate import demo_dir
from tests.cli.test_adjust import _args


@pytest.fixture()
def scene(tmp_path):
    d = tmp_path / "in"
    shutil.copytree(demo_dir(), d)
    return d


def test_help_documents_exit_codes(capsys):
    with pytest.raises(SystemExit):
        main(["adjust", "--help"])
    text = capsys.readouterr().out
    assert "exit status:" in text and "--keep-blunders" in text
    assert all(f"\n    {k}  " in text for k in range(5))
    # help text on every option
    assert "\n  --quiet " in text and "-o DIR, --out DIR" in text and "--image-origin" in text


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_out_refused_before_computing(scene, tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        assert main(_args(scene, "--out", str(ro / "res"))) == 2
    finally:
        ro.chmod(0o700)
    err = capsys.readouterr().err
    assert "--out" in err and "not writable" in err and "Traceback" not in err


def test_out_that_is_a_file_refused_before_computing(scene, capsys):
    assert main(_args(scene, "--out", str(scene / "truth.json"))) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "not a folder" in err and "Traceback" not in err


def test_out_over_an_input_refused_before_computing(scene, capsys):
    # an input named like an output in the --out folder
    shutil.copy(scene / "ground.csv", scene / "report.txt")
    args = _args(scene, "--out", str(scene))
    args[args.index(str(scene / "ground.csv"))] = str(scene / "report.txt")
    assert main(args) == 2
    assert "over an input" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("extra", "existing"),
    [((), "fore_RPC.TXT"), (("--rpc-format", "rpb"), "aft.RPB"), ((), "report.json")],
)
def test_existing_output_refused_before_computing(scene, tmp_path, capsys, monkeypatch, extra,
                                                  existing):  # fmt: skip
    # the pre-check checks exactly the files the writer writes (not old names)
    import jaxgeo.bundle

    def never(*args, **kwargs):
        raise AssertionError("computed before --out was checked")

    monkeypatch.setattr(jaxgeo.bundle, "adjust_files", never)
    out = tmp_path / "o"
    out.mkdir()
    (out / existing).write_text("keep me")
    assert main(_args(scene, "--bias", "shift", "--out", str(out), *extra)) == 2
    err = capsys.readouterr().err
    assert f"{out / existing}: exists" in err and "--overwrite" in err
    assert (out / existing).read_text() == "keep me"
    assert sorted(p.name for p in out.iterdir()) == [existing]


def test_failed_write_keeps_the_report(scene, tmp_path, capsys, monkeypatch):
    import jaxgeo.bundle._files as files

    def fail(*args, **kwargs):
        raise PermissionError("disk says no")

    monkeypatch.setattr(files, "write_outputs", fail)
    assert main(_args(scene, "--bias", "shift", "--out", str(tmp_path / "o"))) == 4
    cap = capsys.readouterr()
    assert "RMS_E" in cap.out and "writing -o/--out failed: disk says no" in cap.err


def test_a_failure_while_the_tables_are_written_leaves_no_file(scene, tmp_path, monkeypatch):
    """Every output goes to its temporary file first (the CSV tables are streamed: seconds at
    100 000 points) and all are renamed at the end: a failure or an interruption while the
    residual table is formed leaves no output file, not the ones written before it."""
    import jaxgeo.bundle._export as export

    real = export.write_csv

    def fail_on_residuals(path, header, rows):
        if "vx_px" in header:
            raise OSError("disk full")
        real(path, header, rows)

    monkeypatch.setattr(export, "write_csv", fail_on_residuals)
    out = tmp_path / "o"
    assert main(_args(scene, "--bias", "shift", "--out", str(out))) == 4
    assert not out.exists() or list(out.iterdir()) == []


def test_gcp_a_kilometre_off_is_named(scene, capsys):
    path = scene / "ground.csv"
    rows = list(csv.reader(path.read_text().splitlines()))
    header = rows[0]
    i = next(k for k, r in enumerate(rows[1:], 1) if r[header.index("role")] == "gcp")
    pid = rows[i][0]
    rows[i][header.index("lat")] = f"{float(rows[i][header.index('lat')]) + 0.009:.9f}"
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")
    assert main(_args(scene, "--bias", "shift")) == 0
    out = capsys.readouterr().out
    assert f"GCP {pid!r}: ground coordinates" in out and "removed" in out


def test_an_adjustment_refused_beside_direct_georeferencing_is_named(scene, capsys):
    """Direct georeferencing of the check points runs on a thread beside the adjustment
    (``jaxgeo.bundle._files``): when the adjustment refuses its input, its error is the one
    reported, with nothing written, and the command ends (the thread's work done or dropped)."""
    path = scene / "ground.csv"
    text = path.read_text().replace(",gcp,", ",check,")
    path.write_text(text.replace(",check,", ",gcp,", 1))  # one GCP left
    out = scene / "out"
    assert main(_args(scene, "--bias", "affine", "--out", str(out))) == 2
    err = capsys.readouterr().err
    assert "error: singular normal equations: not determined: parameter(s) fore.bias" in err, err
    assert "Traceback" not in err and not out.exists()


BAD_OPTIONS = [
    (("--loss-scale", "-1"), "--loss-scale must be a positive number"),
    (("--loss-scale", "nan"), "--loss-scale must be a positive number"),
    (("--max-steps", "0"), "--max-steps must be at least 1"),
    (("--tie-height-sigma-m", "0"), "--tie-height-sigma-m must be a positive number"),
    (("--bias-prior-shift-px", "-2"), "--bias-prior-shift-px must be a positive number"),
    (("--jitter-knot-lines", "0"), "--jitter-knot-lines must be a positive number"),
    (("--geoid", "egm96"), "--geoid applies to a DEM"),
    (("--dem-height", "orthometric"), "--dem-height applies to a DEM"),
    (("--dem-offset-m", "3"), "--dem-offset-m applies to --dem heights only"),
    (("--model", "nope=x.RPB"), "IMG one of the images"),
]


@pytest.mark.parametrize(("extra", "words"), BAD_OPTIONS, ids=[b[0][0] for b in BAD_OPTIONS])
def test_bad_options_named_by_their_flag(scene, capsys, extra, words):
    """Errors name the options (jaxgeo adjust and jaxgeo strip share them), never a library
    parameter (loss_scale, max_steps)."""
    assert main(_args(scene, *extra)) == 2
    err = capsys.readouterr().err
    assert words in err and "loss_scale" not in err and "max_steps" not in err, err
