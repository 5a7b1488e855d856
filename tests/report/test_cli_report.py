"""``--report`` on the commands: ``adjust`` on the embedded demo block, ``dsm``, ``ortho`` and
``coregister`` on a small simulated stereo scene (200 px: one pair, about 40 s on the shared
2-core machine, most of it the DSM's matching; the module makes it once). The page goes where
docs/cli-conventions.md says, is listed in the JSON, is checked before any computation (an
existing page refused, exit 2, without ``--overwrite``) and needs ``-o`` for adjust."""

import contextlib
import io
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
import rasterio

from jaxgeo.cli import main
from jaxgeo.simulate import demo_dir
from tests.report.conftest import sections


def run(*argv) -> tuple[int, dict]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main([*argv, "--json", "--quiet"])
    return code, json.loads(out.getvalue().strip().splitlines()[-1])


def adjust_argv(d):
    return ["adjust", "--image", f"fore={d / 'fore.txt'}", "--image", f"aft={d / 'aft.txt'}",
            "--ground", str(d / "ground.csv"), "--observations", str(d / "observations.csv"),
            "--bias", "shift"]  # fmt: skip


def test_adjust_report_on_the_demo(tmp_path):
    d = tmp_path / "in"
    shutil.copytree(demo_dir(), d)
    out = tmp_path / "out"
    code, data = run(*adjust_argv(d), "--report", "-o", str(out))
    assert code == 0 and str(out / "report.html") in data["written"]
    page = sections(out / "report.html")
    assert len(page.sections["Residuals per image"]) == 2 and not page.forbidden
    assert all(red_pixels(src) == 0 for src in page.sections["Residuals per image"])
    # refused before any computation when the page exists (and nothing else is written)
    again = tmp_path / "again"
    again.mkdir()
    (again / "report.html").write_text("mine")
    code, data = run(*adjust_argv(d), "--report", "-o", str(again))
    assert code == 2 and "report.html" in data["error"] and "--overwrite" in data["error"]
    assert (again / "report.html").read_text() == "mine" and len(list(again.iterdir())) == 1


def test_adjust_report_needs_an_output_folder(tmp_path):
    d = tmp_path / "in"
    shutil.copytree(demo_dir(), d)
    code, data = run(*adjust_argv(d), "--report")
    assert code == 2 and "-o DIR" in data["error"]


def test_commands_start_without_matplotlib():
    """--report imports matplotlib when it writes, not when a command starts."""
    code = (
        "import sys\nfrom jaxgeo.cli import main\nfor c in ('adjust', 'dsm', 'ortho', "
        "'coregister', 'strip'):\n    try:\n        main([c, '--help'])\n    except SystemExit:"
        "\n        pass\nprint('LOADED' if 'matplotlib' in sys.modules else 'NOT LOADED')"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, check=True).stdout  # fmt: skip
    assert out.strip().endswith("NOT LOADED") and "--report" in out


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    w = tmp_path_factory.mktemp("scene")
    code, _ = run("simulate", "stereo-scene", "--size", "200", "--seed", "5203", "--out",
                  str(w / "s"))  # fmt: skip
    assert code == 0
    code, dsm = run("dsm", str(w / "s" / "left.tif"), str(w / "s" / "right.tif"), "--res", "1",
                    "--report", "-o", str(w / "dsm.tif"))  # fmt: skip
    assert code == 0
    return w, dsm


def test_dsm_report_beside_the_dsm(scene):
    w, dsm = scene
    assert dsm["report"] == str(w / "dsm.report.html")
    page = sections(w / "dsm.report.html")
    for heading in ("Relief", "Where the heights come from", "Height uncertainty"):
        assert len(page.sections[heading]) == 1, heading
    # a second run: the page exists (refused before any computation, the DSM too)
    code, data = run("dsm", str(w / "s" / "left.tif"), str(w / "s" / "right.tif"), "--report",
                     "-o", str(w / "other.tif"))  # fmt: skip
    assert code == 0 and (w / "other.report.html").exists()  # another name: its own page
    (w / "third.report.html").write_text("mine")
    code, data = run("dsm", str(w / "s" / "left.tif"), str(w / "s" / "right.tif"), "--report",
                     "-o", str(w / "third.tif"))  # fmt: skip
    assert code == 2 and "third.report.html" in data["error"]
    assert not (w / "third.tif").exists()


def test_coregister_and_ortho_reports(scene):
    w, _ = scene
    code, data = run("coregister", str(w / "dsm.tif"), str(w / "s" / "truth_dsm.tif"), "-o",
                     str(w / "aligned.tif"), "--report")  # fmt: skip
    assert code in (0, 1) and data["report"] == str(w / "aligned.report.html")
    assert len(sections(w / "aligned.report.html").sections["DSM - REF before and after"]) == 2
    with rasterio.open(w / "s" / "truth_dsm.tif") as f:  # an ortho inside the DEM
        b, crs = f.bounds, f.crs.to_string()
    inside = [str(v) for v in (b.left + 10, b.bottom + 10, b.right - 10, b.top - 10)]
    code, data = run("ortho", str(w / "s" / "left.tif"), "--dem", str(w / "s" / "truth_dsm.tif"),
                     "--crs", crs, "--bounds", *inside, "--res", "1", "--report",
                     "-o", str(w / "ortho.tif"))  # fmt: skip
    assert code == 0, data
    assert data["report"] == str(w / "ortho.report.html")
    assert len(sections(w / "ortho.report.html").sections["Quicklook"]) == 1


def red_pixels(src: str) -> int:
    """Pixels of the gross errors' red (#d62728) in a page's PNG figure."""
    import base64

    from PIL import Image

    png = base64.b64decode(src.split(",", 1)[1])
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)
    return int(np.sum(np.abs(rgb - (214, 39, 40)).sum(axis=-1) < 30))


def test_adjust_report_marks_a_gross_error_in_red(tmp_path):
    """One observation moved by 25 px: flagged by snooping (with its partner: the point has
    two rays), counted in the table and drawn in red in both images' figures (the clean demo's
    have no red: test_adjust_report_on_the_demo)."""
    d = tmp_path / "in"
    shutil.copytree(demo_dir(), d)
    lines = (d / "observations.csv").read_text().splitlines()
    header = lines[0].split(",")
    row = lines[5].split(",")
    row[header.index("x")] = repr(float(row[header.index("x")]) + 25.0)
    lines[5] = ",".join(row)
    (d / "observations.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    code, data = run(*adjust_argv(d), "--report", "-o", str(out))
    assert code == 0 and {b["id"] for b in data["blunders"]} == {row[0]}
    text = (out / "report.html").read_text()
    assert f"<td>observations flagged as gross errors</td><td>{len(data['blunders'])}</td>" in text
    for src in sections(out / "report.html").sections["Residuals per image"]:
        assert red_pixels(src) > 30  # the red arrow and its legend
