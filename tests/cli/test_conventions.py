"""What every sub-command shares: interruption, errors without tracebacks, output guards, images
with their pixel frame, DEM sanity, help text and exit codes."""

import hashlib
import os
import pathlib
import re
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest
import rasterio

from jaxgeo.cli import COMMANDS, build_parser, main
from jaxgeo.io import ImageError, open_image, read_dem

REAL = pathlib.Path(__file__).parents[1] / "data" / "real"


def digest(path) -> str:
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_interrupted_command_exits_130_leaving_nothing(shared_data, tmp_path, signum):
    triplet = shared_data / "s2p_triplet"
    out = tmp_path / "out"
    out.mkdir()
    env = {**os.environ, "JAXGEO_TYPECHECK": "0"}
    cmd = [sys.executable, "-m", "jaxgeo.cli", "dsm", str(triplet / "img_02.tif"),
           str(triplet / "img_01.tif"), "--quiet", "-o", str(out / "dsm.tif")]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    time.sleep(6.0)  # inside the computation (imports and the first stages)
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, (proc.returncode, stderr[-2000:])
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1] == "jaxgeo dsm: interrupted; no output was written"
    assert list(out.iterdir()) == []  # no output, no temporary file


def test_internal_error_is_one_line_exit_70(monkeypatch, capsys):
    import jaxgeo.cli._dsm as dsm

    def broken(args):
        raise RuntimeError("boom")

    monkeypatch.setattr(dsm, "run", broken)
    assert main(["dsm", "a.tif", "b.tif", "-o", "x.tif"]) == 70
    err = capsys.readouterr().err
    assert (
        err.startswith("jaxgeo dsm: internal error (RuntimeError: boom)") and err.count("\n") == 1
    )


def test_every_option_has_help_and_every_command_its_exit_codes():
    for name in COMMANDS:
        parser = build_parser(name)
        sub = next(a for a in parser._actions if a.dest == "command").choices[name]
        kinds = [sub]
        for action in sub._actions:
            if hasattr(action, "choices") and isinstance(action.choices, dict):
                kinds += list(action.choices.values())  # simulate's kinds
        for p in kinds:
            for action in p._actions:
                if action.dest in ("help", "command", "kind"):
                    continue
                assert action.help, f"jaxgeo {name}: option {action.option_strings} has no help"
        assert "exit status" in (sub.epilog or ""), f"jaxgeo {name}: no exit codes in --help"


def test_output_equal_to_an_input_is_refused_even_with_overwrite(shared_data, tmp_path, capsys):
    triplet = shared_data / "s2p_triplet"
    left, right = tmp_path / "img_02.tif", tmp_path / "img_01.tif"
    left.write_bytes((triplet / "img_02.tif").read_bytes())
    right.write_bytes((triplet / "img_01.tif").read_bytes())
    before = digest(right)
    argv = ["dsm", str(left), str(right), "--quiet", "--overwrite", "-o"]
    assert main([*argv, str(right)]) == 2
    assert "is an input of the command" in capsys.readouterr().err
    assert main([*argv, str(tmp_path / "." / "img_01.tif")]) == 2  # another spelling of it
    link = tmp_path / "link.tif"
    link.symlink_to(right)
    assert main([*argv, str(link)]) == 2  # a link to it
    assert digest(right) == before


@pytest.mark.parametrize(
    "options, message",
    [
        (["--crs", "EPSG:4326"], "not a projected CRS"),
        (["--crs", "EPSG:99999999"], "not a CRS PROJ knows"),
        (["--res", "0"], "expected a positive cell size"),
        (["--res", "0.0005"], "more than --max-cells"),
        (["--res", "1e6"], "lower --res"),
        (["--roi", "900", "900", "500", "500"], "not inside"),
        (["--model", "nope.tif=x.RPB"], "IMG one of the images"),
        (["--image-origin", "img_02=a,b"], "expected IMG=COL,ROW"),
    ],
)
def test_dsm_options_checked_before_any_computation(shared_data, tmp_path, capsys, options,
                                                    message):  # fmt: skip
    triplet = shared_data / "s2p_triplet"
    out = tmp_path / "dsm.tif"
    argv = ["dsm", str(triplet / "img_02.tif"), str(triplet / "img_01.tif"), *options]
    assert main([*argv, "--quiet", "-o", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_output_folder_missing_not_a_folder_or_read_only(shared_data, tmp_path, capsys):
    triplet = shared_data / "s2p_triplet"
    argv = ["dsm", str(triplet / "img_02.tif"), str(triplet / "img_01.tif"), "--quiet", "-o"]
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main([*argv, str(tmp_path / "missing" / "d.tif")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main([*argv, str(afile / "d.tif")]) == 2
    assert "is not a folder" in capsys.readouterr().err
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o555)
        assert main([*argv, str(ro / "d.tif")]) == 2
        assert "not writable" in capsys.readouterr().err


def _crop(tmp_path, transform=None, crs=None):
    src = REAL / "ventoux" / "left_image.tif"
    with rasterio.open(src) as f:
        data, profile = f.read(), f.profile
    profile.update(transform=transform or rasterio.Affine.identity(), crs=crs)
    out = tmp_path / "crop.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(out, "w", **profile) as f:
            f.write(data)
    return out


def test_crop_pixel_frame_read_from_its_geotransform():
    geom = REAL / "phr_ventoux__left_image.geom"
    crop = open_image(REAL / "ventoux" / "left_image.tif", model=geom)
    full = open_image(model=geom)
    assert crop.origin == (5000.0, 5000.0) and crop.size == (500, 500)
    ground = np.array([[5.27, 44.17, 900.0]])
    np.testing.assert_allclose(
        np.asarray(crop.model.project(ground)) + 5000.0, np.asarray(full.model.project(ground)),
        atol=1e-9,
    )  # fmt: skip
    # only a model: the RPC's domain bounds the pixels; a raster: its size does
    assert full.domain()[2] > 10_000 and crop.domain() == (-0.5, -0.5, 499.5, 499.5)


def test_image_origin_override_and_conflict(tmp_path):
    geom = REAL / "phr_ventoux__left_image.geom"
    plain = _crop(tmp_path)  # no geotransform: the frame must be given
    image = open_image(plain, model=geom, origin=(5000, 5000))
    assert image.origin == (5000.0, 5000.0)
    with pytest.raises(ImageError, match="conflicts with the crop origin 5000 5000"):
        open_image(REAL / "ventoux" / "left_image.tif", model=geom, origin=(0, 0))
    with pytest.raises(ImageError, match="no sensor model in the image"):
        open_image(REAL / "ventoux" / "left_image.tif")
    odd = _crop(tmp_path, transform=rasterio.Affine(2.0, 0, 10, 0, 2.0, 10))
    with pytest.raises(ImageError, match="neither a map georeferencing"):
        open_image(odd, model=geom)


def test_dem_void_markers_are_nodata_with_a_warning(tmp_path):
    dem_path = REAL / "ventoux" / "dem" / "N44E005_srtm90.tif"
    with rasterio.open(dem_path) as f:
        z, profile = f.read(1), f.profile
    assert (z == -32768).any()
    profile.update(nodata=None)  # the voids are no longer declared
    undeclared = tmp_path / "voids.tif"
    with rasterio.open(undeclared, "w", **profile) as f:
        f.write(z, 1)
    with pytest.warns(UserWarning, match=r"-32768.*read as nodata"):
        dem = read_dem(undeclared)
    rows, cols = np.nonzero(z == -32768)
    lon, lat = rasterio.transform.xy(profile["transform"], rows[:1], cols[:1])
    with pytest.raises(ValueError, match="nodata cells of the DEM"):
        dem(np.array([[lon[0], lat[0]]]))


def test_dem_height_reference_is_described():
    dem = read_dem(
        REAL / "ventoux" / "dem" / "N44E005_srtm90.tif",
        geoid=REAL / "ventoux" / "dem" / "egm96_15_crop_lon3-8_lat42-47.gtx",
    )
    assert "orthometric heights + egm96_15_crop_lon3-8_lat42-47.gtx" in dem.describe()


def test_dem_heights_outside_the_model_validity_warn():
    image = open_image(model=REAL / "phr_ventoux__left_image.geom")
    lo, hi = image.validity_heights()
    assert image.check_heights(lo + 1, hi - 1, "dem.tif") is None
    with pytest.warns(UserWarning, match="leave the validity range"):
        image.check_heights(lo - 400, hi, "dem.tif")


def _parsers():
    """``(command line, parser)`` of every command and sub-command."""
    import argparse

    out = []
    for name in COMMANDS:
        sub = build_parser(name)._subparsers._group_actions[0].choices[name]
        out.append((f"jaxgeo {name}", sub))
        for action in sub._actions:
            if isinstance(action, argparse._SubParsersAction):
                out += [(f"jaxgeo {name} {k}", p) for k, p in action.choices.items()]
    return out


# simulate's kinds get --quiet/--json in the simulate branch (drop this once merged)
QUIET_JSON_PENDING = {"jaxgeo simulate", "jaxgeo simulate cartosat1",
                      "jaxgeo simulate carto2s-strip"}  # fmt: skip


def test_every_command_has_quiet_json_and_names_the_conventions_page():
    from jaxgeo.cli._common import SEE_CONVENTIONS

    page = (pathlib.Path(__file__).parents[2] / "docs" / "cli-conventions.md").read_text()
    for path, parser in _parsers():
        options = {o for a in parser._actions for o in a.option_strings}
        has_kinds = any(isinstance(a.choices, dict) for a in parser._actions if a.choices)
        if path not in QUIET_JSON_PENDING and not has_kinds:
            assert {"--quiet", "--json"} <= options, f"{path}: --quiet/--json missing"
        if path.count(" ") == 1:  # a command: its exit codes, then the page
            assert (parser.epilog or "").rstrip().endswith(SEE_CONVENTIONS), path
            status = parser.epilog.partition("exit status:")[2]
            for code in re.findall(r"^\s+(\d+)\s", status, re.M):
                assert f"\n| {code} |" in page, f"{path}: exit code {code} not on the page"
    for option in (
        "-o/--out",
        "--overwrite",
        "--quiet",
        "--json",
        "--model IMG=FILE",
        "--image-origin",
        "--dem FILE",
        "--dem-height",
        "--geoid",
        "--tile N",
        "--workers",
        "--scheduler",
        "--retries",
        "--resume",
        "--plan",
        "--tolerance",
    ):
        assert f"`{option}" in page, option  # fmt: skip
