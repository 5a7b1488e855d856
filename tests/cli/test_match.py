"""``jaxgeo match``: true ties with the default options on real pairs, one summary per pair,
bad options as named errors (exit 2, nothing written), inputs never changed."""

import hashlib
import json
import shutil

import numpy as np
import pytest

from jaxgeo.cli import main
from jaxgeo.io import open_image, read_dem, read_observations
from jaxgeo.stereo import triangulate
from tests.stereo.test_tie_points import dsm_heights


def digests(paths):
    return {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}


def pair_points(obs, a, b):
    images = np.asarray(obs.images)
    return obs.xy[images == a], obs.xy[images == b]


def assert_no_duplicates(obs):
    rows = {(img, float(x), float(y)) for img, (x, y) in zip(obs.images, obs.xy, strict=True)}
    assert len(rows) == len(obs)


def test_defaults_on_a_triplet_pair(shared_data, tmp_path, capsys):
    folder = shared_data / "s2p_triplet"
    img2, img3 = folder / "img_02.tif", folder / "img_03.tif"
    before = digests([img2, img3])
    out = tmp_path / "ties.csv"
    assert main(["match", str(img2), str(img3), "-o", str(out), "--json", "--quiet"]) == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out)  # one object on stdout
    assert captured.err == ""  # --quiet: no progress
    obs = read_observations(out)
    assert result["n_points"] == len(obs) // 2 == result["points_by_views"]["2"]
    assert result["n_observations"] == len(obs) and result["out"] == str(out)
    (pair,) = result["pairs"]
    assert pair["images"] == ["img_02", "img_03"] and pair["height_source"] == "coarse matching"
    assert pair["n_kept"] == result["n_points"]
    assert set(obs.images) == {"img_02", "img_03"} and np.all(obs.sigma_px == 0.5)
    assert_no_duplicates(obs)
    xy2, xy3 = pair_points(obs, "img_02", "img_03")
    models = [open_image(p).model for p in (img2, img3)]
    ground, _ = triangulate(models, np.stack([xy2, xy3], axis=1))
    ref = dsm_heights(ground, folder / "expected_dsm.tif")
    valid = np.isfinite(ref)
    dh = ground[valid, 2] - ref[valid]
    # measured: 7303 ties, 3438 on s2p's DSM, 96.8 % within 5 m, median +2.4 m (relative
    # pointing of the pair, not corrected here); before: 1066 ties, 50 % of 109
    assert valid.sum() > 2000 and np.mean(np.abs(dh) <= 5.0) >= 0.9
    assert digests([img2, img3]) == before


@pytest.fixture
def ventoux_copy(real_data, tmp_path):
    """The Ventoux crops and their models copied (the tests name them as outputs)."""
    folder = tmp_path / "in"
    folder.mkdir()
    files = []
    for side in ("left", "right"):
        files.append(shutil.copy(real_data / "ventoux" / f"{side}_image.tif", folder))
        files.append(shutil.copy(real_data / f"phr_ventoux__{side}_image.geom", folder))
    dem_dir = real_data / "ventoux" / "dem"
    files.append(shutil.copy(dem_dir / "N44E005_srtm90.tif", folder))
    files.append(shutil.copy(dem_dir / "egm96_15_crop_lon3-8_lat42-47.gtx", folder))
    return [folder / f for f in map(str, files)]


def ventoux_args(files):
    left, left_geom, right, right_geom = (str(f) for f in files[:4])
    return ["match", left, right, "--model", f"left_image={left_geom}",
            "--model", f"right_image={right_geom}"]  # fmt: skip


@pytest.mark.parametrize("use_dem", [False, True], ids=["defaults", "dem"])
def test_ventoux_crops(ventoux_copy, tmp_path, capsys, use_dem):
    files = ventoux_copy
    before = digests(files)
    out = tmp_path / "ties.csv"
    dem_args = ["--dem", str(files[4]), "--geoid", str(files[5])] if use_dem else []
    assert main([*ventoux_args(files), *dem_args, "-o", str(out)]) == 0
    captured = capsys.readouterr()
    # the human summary: kept of candidates, rejections by check, range and its source, spread
    assert "left_image - right_image: " in captured.out and " ties kept of " in captured.out
    assert "duplicate" in captured.out and "p5/p50/p95" in captured.out
    assert "offset across the epipolar curves -4.7" in captured.out
    assert ("(dem;" if use_dem else "(coarse matching,") in captured.out
    if use_dem:
        assert "orthometric heights + egm96_15_crop_lon3-8_lat42-47.gtx undulation" in captured.err
    obs = read_observations(out)
    assert_no_duplicates(obs)
    xy1, xy2 = pair_points(obs, "left_image", "right_image")
    # crop pixels, not the full product's: the crops' pixel-space geotransform was applied
    assert np.all((xy1 > -1) & (xy1 < 500)) and np.all((xy2 > -1) & (xy2 < 498))
    left = open_image(files[0], model=files[1])
    right = open_image(files[2], model=files[3])
    ground, _ = triangulate([left.model, right.model], np.stack([xy1, xy2], axis=1))
    srtm = read_dem(files[4], height="orthometric", geoid=files[5])(ground[:, :2])
    # measured: ~700 ties, all within 20 m of SRTM + EGM96 (median +3.7 m); before: 37 ties
    assert len(xy1) > 400 and np.mean(np.abs(ground[:, 2] - srtm) <= 20.0) >= 0.9
    assert digests(files) == before


BAD_OPTIONS = {
    "heights reversed": (["--heights", "500", "-500"], "--heights 500 -500: need finite HMIN"),
    "heights not finite": (["--heights", "nan", "500"], "--heights nan 500"),
    "sigma zero": (["--sigma", "0"], "--sigma 0: must be a number > 0"),
    "tol negative": (["--tol", "-1"], "--tol -1: must be a number > 0"),
    "tolerance not finite": (["--tolerance", "inf"], "--tolerance inf: must be a number > 0"),
    "roi outside": (["--roi", "400", "0", "200", "100"], "--roi 400 0 200 100: not inside"),
    "roi empty": (["--roi", "0", "0", "0", "100"], "--roi 0 0 0 100: not inside"),
    "geoid without dem": (["--geoid", "egm96"], "--geoid applies to a DEM"),
}


@pytest.mark.parametrize("case", BAD_OPTIONS, ids=list(BAD_OPTIONS))
def test_bad_options_are_named_errors(ventoux_copy, tmp_path, capsys, case):
    options, message = BAD_OPTIONS[case]
    before = digests(ventoux_copy)
    out = tmp_path / "ties.csv"
    assert main([*ventoux_args(ventoux_copy), *options, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxgeo match: error: ") and message in err
    assert "Traceback" not in err and not out.exists()
    assert digests(ventoux_copy) == before


@pytest.mark.parametrize("which", ["image", "model", "dem"])
def test_never_writes_over_an_input(ventoux_copy, capsys, which):
    files = ventoux_copy
    before = digests(files)
    target = {"image": files[0], "model": files[1], "dem": files[4]}[which]
    argv = [*ventoux_args(files), "--dem", str(files[4]), "--geoid", str(files[5])]
    assert main([*argv, "-o", str(target), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert f"{target}: this output is an input of the command" in err
    assert digests(files) == before


def test_output_folder_missing_and_existing_output(ventoux_copy, tmp_path, capsys):
    args = ventoux_args(ventoux_copy)
    missing = tmp_path / "nowhere" / "ties.csv"
    assert main([*args, "-o", str(missing)]) == 2
    assert "the output folder" in capsys.readouterr().err and not missing.parent.exists()
    existing = tmp_path / "ties.csv"
    existing.write_text("keep me\n")
    assert main([*args, "-o", str(existing)]) == 2
    assert "exists; pass --overwrite" in capsys.readouterr().err
    assert existing.read_text() == "keep me\n"
    assert main(["match", str(ventoux_copy[0]), "-o", str(tmp_path / "one.csv")]) == 2
    assert "at least two images" in capsys.readouterr().err


def test_help_names_every_option(capsys):
    with pytest.raises(SystemExit):
        main(["match", "--help"])
    text = capsys.readouterr().out
    for option in (
        "--dem",
        "--dem-height",
        "--geoid",
        "--heights",
        "--roi",
        "--tolerance",
        "--tol",
        "--sigma",
        "--model",
        "--image-origin",
        "--overwrite",
        "--quiet",
        "--json",
        "exit status",
    ):
        assert option in text  # fmt: skip
