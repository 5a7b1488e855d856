"""The table of issue 53's bad inputs and unclear errors through the CLI: each case ends with its
exit status and a message naming the option, file or other run at fault, with ``--json`` exactly
one JSON object on stdout (``ok``, ``exit_code``, ``error``), and no input changed (hashes
before and after). Every case fails before any computation (fast; a DSM's DEM is checked against
the tie points of one window first, ~10 s); the cases of a second run, a killed run and the
environment are the tests after the table."""

import hashlib
import json
import os
import pathlib
import shutil
import subprocess
import sys
import time

import pytest

from jaxgeo.cli import main
from jaxgeo.io._atomic import CLAIM_SUFFIX
from jaxgeo.tiles.internal import max_local_workers

REPO = pathlib.Path(__file__).resolve().parents[2]
REAL = REPO / "tests" / "data" / "real"
DEMO = REPO / "jaxgeo" / "data" / "cartosat1_demo"


def digest(path) -> str:
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


@pytest.fixture
def workspace(tmp_path):
    """Copies of the inputs (the Ventoux crops, their models, SRTM, the demo scene's RPCs and
    tables, an observations table with its header only) in a folder of their own."""
    src = tmp_path / "in"
    src.mkdir()
    for name in ("left_image.tif", "right_image.tif"):
        shutil.copy(REAL / "ventoux" / name, src / name)
    for side in ("left", "right"):
        shutil.copy(REAL / f"phr_ventoux__{side}_image.geom", src / f"{side}.geom")
    shutil.copy(REAL / "ventoux" / "dem" / "N44E005_srtm90.tif", src / "srtm.tif")
    _wrong_dems(src / "srtm.tif")
    for name in ("fore.txt", "aft.txt", "ground.csv", "observations.csv"):
        shutil.copy(DEMO / name, src / name)
    header = (DEMO / "observations.csv").read_text().splitlines()[0]
    (src / "header_only.csv").write_text(header + "\n")
    out = tmp_path / "out"
    out.mkdir()
    hashes = {p: digest(p) for p in src.iterdir()}
    yield src, out
    for path, value in hashes.items():
        assert digest(path) == value, f"{path.name} changed"
    assert sorted(p.name for p in src.iterdir()) == sorted(p.name for p in hashes)


def _wrong_dems(srtm: pathlib.Path) -> None:
    """Beside the SRTM tile (EGM96 heights, 470..580 m under the Ventoux crops): the same in feet
    (undeclared, and declared as the band's unit; capped at 8900, below the heights no terrain
    has, whose warning would be a second line), +500 m and +2000 m."""
    import numpy as np
    import rasterio

    with rasterio.open(srtm) as src:
        z, profile = src.read(1), src.profile
    void = z == profile["nodata"]
    feet = np.minimum(np.round(z / 0.3048), 8900)
    for name, values, units in (("srtm_feet.tif", feet, None),
                                ("srtm_ft_declared.tif", feet, ("ft",)),
                                ("srtm_plus500.tif", z + 500, None),
                                ("srtm_plus2000.tif", z + 2000, None)):  # fmt: skip
        with rasterio.open(srtm.parent / name, "w", **profile) as dst:
            dst.write(np.where(void, z, values).astype(z.dtype), 1)
            if units:
                dst.units = units


PAIR = ["{in}/left_image.tif", "{in}/right_image.tif", "--model", "left_image={in}/left.geom",
        "--model", "right_image={in}/right.geom"]  # fmt: skip
ORTHO = ["ortho", "{in}/left_image.tif", "--model", "{in}/left.geom", "--dem", "{in}/srtm.tif"]
ADJUST = ["adjust", "{in}/fore.txt", "{in}/aft.txt", "--ground", "{in}/ground.csv"]
DSM_DEM = ["dsm", *PAIR, "--geoid", "egm96", "-o", "{out}/d.tif", "--dem"]
ORTHO_DEM = ["ortho", "{in}/left_image.tif", "--model", "{in}/left.geom", "--geoid", "egm96",
             "-o", "{out}/o.tif", "--dem"]  # fmt: skip

# (case, argv with {in}/{out} placeholders, expected exit status, words of the message)
CASES = [
    ("match: --tol 1e6 (the matching never ends)",
     ["match", *PAIR, "--tol", "1e6", "-o", "{out}/t.csv"], 2, ["--tol 1e+06", "at most 200 px"]),
    ("match: --tolerance wider than a quarter of the image",
     ["match", *PAIR, "--tolerance", "150", "-o", "{out}/t.csv"], 2,
     ["--tolerance 150", "at most 123 px", "right_image.tif", "498 x 495"]),
    ("match: --tol nan", ["match", *PAIR, "--tol", "nan", "-o", "{out}/t.csv"], 2,
     ["--tol nan", "> 0"]),
    ("dsm: --workers 1000 (hundreds of processes on a few cores)",
     ["dsm", *PAIR, "--workers", "1000", "-o", "{out}/d.tif"], 2,
     [f"--workers must be >= 0 and <= {max_local_workers()}", "got 1000", "--scheduler"]),
    ("dsm: --workers with --scheduler (it would do nothing)",
     ["dsm", *PAIR, "--workers", "1", "--scheduler", "tcp://127.0.0.1:1", "-o", "{out}/d.tif"],
     2, ["--workers 1 with --scheduler"]),
    ("dsm: --tile 100000", ["dsm", *PAIR, "--tile", "100000", "-o", "{out}/d.tif"], 2,
     ["--tile must be >= 64 and <= 8192", "got 100000"]),
    ("dsm: --retries 1000", ["dsm", *PAIR, "--retries", "1000", "-o", "{out}/d.tif"], 2,
     ["--retries must be >= 0 and <= 10"]),
    ("ortho: --workers 1000", [*ORTHO, "--workers", "1000", "-o", "{out}/o.tif"], 2,
     ["--workers must be", "two per core"]),
    ("ortho: --tile 10", [*ORTHO, "--tile", "10", "-o", "{out}/o.tif"], 2,
     ["--tile must be >= 64"]),
    ("adjust: an observations table with its header only",
     [*ADJUST, "--observations", "{in}/header_only.csv"], 2,
     ["header_only.csv", "no measurements", "no rows"]),
    ("match: a missing image", ["match", "{in}/nope.tif", "{in}/left_image.tif",
                                "-o", "{out}/t.csv"], 2, ["nope.tif"]),
    ("dsm (tiled): a DEM in feet", [*DSM_DEM, "{in}/srtm_feet.tif", "--tile", "256",
                                    "--workers", "0"], 2,
     ["srtm_feet.tif", "tie points' triangulated heights", "heights in feet", "--heights"]),
    ("dsm: a DEM 500 m too high", [*DSM_DEM, "{in}/srtm_plus500.tif"], 2,
     ["srtm_plus500.tif", "a constant offset of +", "--geoid"]),
    ("ortho: a DEM 2000 m too high (beyond the model's validity range)",
     [*ORTHO_DEM, "{in}/srtm_plus2000.tif"], 2,
     ["srtm_plus2000.tif", "validity range 190..1960 m", "above the range"]),
    ("ortho: a DEM declaring its heights in feet", [*ORTHO_DEM, "{in}/srtm_ft_declared.tif"], 2,
     ["srtm_ft_declared.tif", "in 'ft'", "0.3048"]),
]  # fmt: skip


def _argv(argv, src, out):
    return [a.replace("{in}", str(src)).replace("{out}", str(out)) for a in argv]


def _reply(stdout: str) -> dict:
    """The one JSON object on stdout (nothing else is there)."""
    lines = stdout.strip().splitlines()
    assert len(lines) == 1, stdout
    return json.loads(lines[0])


@pytest.mark.parametrize("case, argv, status, words", CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_a_named_error_with_one_json_object(workspace, capsys, case, argv, status,
                                                         words):  # fmt: skip
    src, out = workspace
    assert main([*_argv(argv, src, out), "--quiet", "--json"]) == status
    captured = capsys.readouterr()
    err = captured.err
    assert "Traceback" not in err and err.startswith(f"jaxgeo {argv[0]}: error: "), err
    assert len(err.strip().splitlines()) == 1, err
    assert all(w in err for w in words), err
    reply = _reply(captured.out)
    assert reply["ok"] is False and reply["exit_code"] == status
    assert all(w in reply["error"] for w in words), reply
    assert list(out.iterdir()) == []  # nothing written, no claim left


def test_a_usage_error_with_json_prints_its_object_too(capsys):
    with pytest.raises(SystemExit) as end:
        main(["match", "a.tif", "--json"])  # -o missing
    assert end.value.code == 2
    reply = _reply(capsys.readouterr().out)
    assert reply["ok"] is False and reply["exit_code"] == 2 and "-o/--out" in reply["error"]


HOLD = """
import sys, time
from jaxgeo.io._atomic import claim_output
claim_output(sys.argv[1], "jaxgeo match a.tif b.tif -o t.csv")
print("claimed", flush=True)
time.sleep(120)
"""


def test_an_output_another_run_is_writing_is_refused_at_once(workspace, capsys):
    """Another process holds the output's claim: the command stops before reading anything,
    naming the path and that run; with --overwrite it runs (and says that the last wins)."""
    src, out = workspace
    target = out / "t.csv"
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(target)], stdout=subprocess.PIPE,
                            text=True)  # fmt: skip
    try:
        assert proc.stdout.readline().strip() == "claimed"
        argv = _argv(["match", *PAIR, "--tol", "1e6", "-o", str(target)], src, out)
        t0 = time.perf_counter()
        assert main([*argv, "--json"]) == 2
        seconds = time.perf_counter() - t0
        captured = capsys.readouterr()
        for text in (captured.err, _reply(captured.out)["error"]):
            assert str(target) in text and f"pid {proc.pid}" in text, text
            assert "another jaxgeo run is writing this output" in text
        assert "--tol" not in captured.err  # refused before the options were even checked
        assert seconds < 5
        # --overwrite: a warning naming the other run, then its own checks
        assert main([*argv, "--overwrite"]) == 2
        err = capsys.readouterr().err
        assert "warning:" in err and f"pid {proc.pid}" in err and "--tol 1e+06" in err
        assert not target.exists()
    finally:
        proc.kill()
        proc.wait()


def test_a_claim_left_by_a_killed_run_is_taken_over(workspace, capsys):
    src, out = workspace
    target = out / "t.csv"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    import socket

    record = {"pid": int(dead.stdout), "host": socket.gethostname(), "command": "jaxgeo match",
              "started": "2026-01-01 00:00:00 UTC", "token": "0"}  # fmt: skip
    (out / ("t.csv" + CLAIM_SUFFIX)).write_text(json.dumps(record))
    argv = _argv(["match", *PAIR, "--tol", "1e6", "-o", str(target)], src, out)
    assert main(argv) == 2  # the claim is taken over; the command then fails on --tol
    err = capsys.readouterr().err
    assert "took over the claim of an earlier run that no longer runs" in err, err
    assert "--tol 1e+06" in err
    assert list(out.iterdir()) == []  # the claim, taken over, is released at the end


def test_two_jaxgeo_processes_writing_one_new_output(tmp_path, capsys):
    """A real second run while the first runs: the second fails at once (exit 2, naming the
    path and the first run), the first completes; no --overwrite anywhere."""
    out = tmp_path / "scene"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    first = subprocess.Popen([sys.executable, "-m", "jaxgeo.cli", "simulate", "cartosat1", "-o",
                              str(out), "--quiet", "--json"], env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)  # fmt: skip
    claim = tmp_path / ("scene" + CLAIM_SUFFIX)
    deadline = time.monotonic() + 120
    while not claim.exists() and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert claim.exists(), first.communicate()
    assert main(["simulate", "cartosat1", "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"pid {first.pid}" in err and str(out) in err and "simulate cartosat1" in err, err
    stdout, stderr = first.communicate(timeout=300)
    assert first.returncode == 0, stderr
    assert (out / "observations.csv").is_file() and not claim.exists()
    reply = _reply(stdout)  # success: the result with ok and exit_code
    assert reply["ok"] is True and reply["exit_code"] == 0 and "error" not in reply
    assert reply["kind"] == "cartosat1" and "observations.csv" in reply["files"]


def test_uncaught_library_warnings_are_lines_of_the_command(workspace):
    """`dsm --heights 5000 6000` leaked Python's warning display (file, line, source line); in
    the command's own process (the suite turns jaxgeo's warnings into errors)."""
    src, out = workspace
    argv = _argv(["dsm", *PAIR, "--heights", "5000", "6000", "-o", "{out}/d.tif"], src, out)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    run = subprocess.run([sys.executable, "-m", "jaxgeo.cli", *argv, "--quiet"], env=env,
                         capture_output=True, text=True, timeout=600)  # fmt: skip
    assert "jaxgeo dsm: warning: the height range 5000..6000 m reaches outside" in run.stderr
    assert "TieWarning" not in run.stderr and ".py:" not in run.stderr, run.stderr


def test_an_unusable_cache_dir_is_said_once_as_a_line(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("")
    env = {**os.environ, "PYTHONPATH": str(REPO), "JAXGEO_CACHE_DIR": str(afile / "sub")}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    argv = ["match", "a.tif", "b.tif", "-o", str(tmp_path / "t.csv")]
    run = subprocess.run([sys.executable, "-m", "jaxgeo.cli", *argv], env=env,
                         capture_output=True, text=True)  # fmt: skip
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 2, run.stderr
    assert (
        lines[0].startswith("jaxgeo match: warning: JAXGEO_CACHE_DIR=") and "not cached" in lines[0]
    )
    assert "UserWarning" not in run.stderr
