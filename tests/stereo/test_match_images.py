"""``match_images``: the library call behind ``jaxgeo match`` gives exactly the observations the
command writes; its settings are checked field by field; a pair with few ties warns, naming it;
no tie at all is a named error carrying the pairs' reports."""

import json
import warnings

import numpy as np
import pytest

from jaxgeo.cli import main
from jaxgeo.io import open_image, read_observations
from jaxgeo.stereo import (
    MatchSettings,
    NoTiesError,
    TieError,
    TieResult,
    TieWarning,
    match_images,
)

# a small ROI of the first image and a tight tolerance: its two pairs keep few ties (28, 17),
# the third pair (whole images) thousands, and 20 points are seen in all three images
TRIPLET_ARGS = ["--roi", "100", "100", "60", "60", "--tolerance", "5"]
TRIPLET_SETTINGS = MatchSettings(roi=(100, 100, 60, 60), epipolar_tol_px=5.0)


@pytest.fixture(scope="module")
def triplet(shared_data):
    folder = shared_data / "s2p_triplet"
    return [folder / f"img_0{k}.tif" for k in (1, 2, 3)]


@pytest.fixture(scope="module")
def library_run(triplet):
    """``match_images`` on the triplet: its result, the progress lines and the warnings."""
    lines = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = match_images(
            [open_image(p) for p in triplet], TRIPLET_SETTINGS, progress=lines.append
        )
    return result, lines, [w for w in caught if issubclass(w.category, TieWarning)]


def test_the_same_observations_as_the_command(triplet, library_run, tmp_path, capsys):
    result, _, _ = library_run
    out = tmp_path / "cli.csv"
    argv = ["match", *map(str, triplet), *TRIPLET_ARGS, "-o", str(out), "--json", "--quiet"]
    assert main(argv) == 0
    printed = json.loads(capsys.readouterr().out)
    cli = read_observations(out)
    obs = result.observations
    assert isinstance(result, TieResult)
    assert obs.point_ids == cli.point_ids and obs.point_ids[0] == "tie0000"
    assert obs.images == cli.images
    np.testing.assert_array_equal(obs.xy, cli.xy)
    np.testing.assert_array_equal(obs.sigma_px, cli.sigma_px)
    # the JSON the command prints is the result's, with the output named
    assert printed == {"out": str(out), "ok": True, "exit_code": 0,
                       **json.loads(json.dumps(result.as_dict()))}  # fmt: skip
    # written by the result: the same file, byte for byte; never over an existing one
    mine = result.write(tmp_path / "lib.csv")
    assert mine.read_bytes() == out.read_bytes()
    with pytest.raises(FileExistsError):
        result.write(mine)
    result.write(mine, overwrite=True)


def test_joined_statistics_and_pair_reports(library_run):
    result, lines, _ = library_run
    assert result.n_points == len(set(result.observations.point_ids)) > 1000
    assert result.points_by_views[3] > 0 and sum(result.points_by_views.values()) == result.n_points
    assert len(result.observations) == sum(v * n for v, n in result.points_by_views.items())
    assert [r.images for r in result.pairs] == [
        ("img_01", "img_02"), ("img_01", "img_03"), ("img_02", "img_03"),
    ]  # fmt: skip
    assert result.pairs[0].as_dict()["images"] == ["img_01", "img_02"]
    first = result.pairs[0].summary()
    assert first[0].startswith("img_01 - img_02: ") and " ties kept of " in first[0]
    assert result.describe().startswith(f"{result.n_points} tie points (")
    assert lines == [
        "SIFT keypoints of img_01 (1/3)", "SIFT keypoints of img_02 (2/3)",
        "SIFT keypoints of img_03 (3/3)", "matching img_01 - img_02", "matching img_01 - img_03",
        "matching img_02 - img_03",
    ]  # fmt: skip


def test_few_ties_warn_naming_the_pair(library_run):
    result, _, caught = library_run
    few = [r for r in result.pairs if r.n_kept < TRIPLET_SETTINGS.few_ties]
    assert few  # the ROI's pairs
    messages = [str(w.message) for w in caught if " ties (do the images overlap?" in str(w.message)]
    assert messages == [
        f"{r.images[0]} - {r.images[1]}: only {r.n_kept} ties (do the images overlap? are the "
        "models right? a larger epipolar_tol_px for a large relative bias?)"
        for r in few
    ]


def test_no_tie_at_all_is_a_named_error_with_the_reports(real_data):
    images = [
        open_image(
            real_data / "ventoux" / f"{s}_image.tif",
            model=real_data / f"phr_ventoux__{s}_image.geom",
        )
        for s in ("left", "right")
    ]
    # the terrain is near 535 m: a search 1800..1950 m triangulates nothing inside it
    settings = MatchSettings(height_range_m=(1800.0, 1950.0))
    with warnings.catch_warnings(record=True), pytest.raises(NoTiesError) as err:
        warnings.simplefilter("always")
        match_images(images, settings)
    assert "no tie point survived the checks in any pair" in str(err.value)
    assert isinstance(err.value, TieError) and isinstance(err.value, ValueError)
    (report,) = err.value.reports
    assert report.images == ("left_image", "right_image") and report.n_kept == 0


def test_images_that_cannot_be_matched_are_named(real_data):
    left = open_image(
        real_data / "ventoux" / "left_image.tif", model=real_data / "phr_ventoux__left_image.geom"
    )
    with pytest.raises(TieError, match="at least two images, got 1"):
        match_images([left])
    with pytest.raises(TieError, match="image names must differ"):
        match_images([left, left])
    right = open_image(
        real_data / "ventoux" / "right_image.tif", model=real_data / "phr_ventoux__right_image.geom"
    )
    with pytest.raises(TieError, match=r"not inside .*left_image.tif \(500 x 500 px\)"):
        match_images([left, right], MatchSettings(roi=(450, 0, 100, 100)))


BAD_SETTINGS = {
    "roi": ({"roi": (0, 0, 10)}, "four integers"),
    "roi five": ({"roi": (0, 0, 10, 10, 10)}, "four integers"),
    "roi empty": ({"roi": (0, 0, 0, 10)}, "width, height > 0"),
    "roi negative": ({"roi": (-1, 0, 10, 10)}, "col, row >= 0"),
    "heights reversed": ({"height_range_m": (900.0, 500.0)}, "HMIN < HMAX"),
    "heights nan": ({"height_range_m": (float("nan"), 500.0)}, "HMIN < HMAX"),
    "heights one": ({"height_range_m": (500.0,)}, "HMIN < HMAX"),
    "tolerance zero": ({"epipolar_tol_px": 0.0}, "must be a number > 0"),
    "tolerance inf": ({"epipolar_tol_px": float("inf")}, "must be a number > 0"),
    "ratio": ({"ratio": 1.5}, "ratio must be in"),
    "dem margin": ({"dem_margin_m": -1.0}, ">= 0"),
    "sigma": ({"sigma_px": 0.0}, "> 0"),
    "few ties": ({"few_ties": -1}, "integer >= 0"),
}


@pytest.mark.parametrize("case", BAD_SETTINGS, ids=list(BAD_SETTINGS))
def test_settings_are_checked_naming_the_field(case):
    fields, message = BAD_SETTINGS[case]
    (name,) = fields
    with pytest.raises(ValueError, match=message) as err:
        MatchSettings(**fields)
    assert isinstance(err.value, TieError) and f"{name}=" in str(err.value)


def test_settings_defaults_and_normalised_values():
    s = MatchSettings()
    assert (s.roi, s.height_range_m, s.epipolar_tol_px, s.sigma_px, s.few_ties) == (
        None, None, 10.0, 0.5, 20,
    )  # fmt: skip
    s = MatchSettings(roi=[1, 2, 30, 40], height_range_m=[100.0, 200.5])
    assert s.roi == (1, 2, 30, 40) and all(type(v) is int for v in s.roi)
    assert s.height_range_m == (100.0, 200.5)
    with pytest.raises(AttributeError):
        s.epipolar_tol_px = 3.0  # frozen
