"""``tie_points``: true ties by default on real Pleiades pairs, checked against independent heights
(s2p's expected DSM for the triplet, SRTM + EGM96 for the Ventoux crops); errors named."""

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from jaxgeo.io import open_image, read_dem
from jaxgeo.models import Biased, ShiftBias
from jaxgeo.stereo import MatchSettings, TieError, tie_points
from jaxgeo.stereo._join import join_ties
from jaxgeo.stereo._matching import sift_features_raster
from jaxgeo.stereo._ties import validity_heights


def dsm_heights(ground, dsm_path):
    """Heights of s2p's expected DSM (UTM 31N, 0.5 m) under ``ground`` lon/lat (NaN off it)."""
    import pyproj

    with rasterio.open(dsm_path) as src:
        band, t = src.read(1), src.transform
    east, north = pyproj.Transformer.from_crs(4326, 32631, always_xy=True).transform(
        ground[:, 0], ground[:, 1]
    )
    inv = ~t
    east, north = np.asarray(east), np.asarray(north)
    col, row = inv.a * east + inv.b * north + inv.c, inv.d * east + inv.e * north + inv.f
    c, r = np.floor(col).astype(int), np.floor(row).astype(int)
    inside = (c >= 0) & (r >= 0) & (c < band.shape[1]) & (r < band.shape[0])
    out = np.full(len(ground), np.nan)
    out[inside] = band[r[inside], c[inside]]
    return out


def true_fraction(ties, reference_h, tol_m):
    """Share of the ties on a valid reference cell whose height is within ``tol_m`` of it, the
    number on valid cells, and the median difference."""
    valid = np.isfinite(reference_h)
    dh = ties.heights_m[valid] - reference_h[valid]
    return float(np.mean(np.abs(dh) <= tol_m)), int(valid.sum()), float(np.median(dh))


def check_bookkeeping(ties):
    rep = ties.report
    assert rep.n_kept == len(ties)
    assert rep.n_kept + sum(rep.rejected.values()) == rep.n_candidates
    # one tie per keypoint location and one-to-one
    assert len(np.unique(ties.xy1, axis=0)) == len(ties) == len(np.unique(ties.xy2, axis=0))
    lo, hi = rep.height_range_m
    assert np.all((ties.heights_m >= lo) & (ties.heights_m <= hi))
    assert rep.heights_m[0] <= rep.heights_m[1] <= rep.heights_m[2]


def test_defaults_give_true_ties_on_the_s2p_triplet(shared_data):
    folder = shared_data / "s2p_triplet"
    im1, im2 = open_image(folder / "img_01.tif"), open_image(folder / "img_02.tif")
    ties = tie_points(im1.model, im2.model, im1.path, im2.path)
    rep = ties.report
    check_bookkeeping(ties)
    # the search range: found by the coarse matching, within the RPC validity (40..1090 m),
    # holding the terrain that s2p's DSM shows, and much narrower than the validity range
    assert rep.height_source == "coarse matching" and rep.n_coarse > 100
    assert rep.validity_m == (40.0, 1090.0)
    with rasterio.open(folder / "expected_dsm.tif") as src:
        dsm = src.read(1)
    terrain = np.nanpercentile(dsm, [1, 99])
    lo, hi = rep.height_range_m
    assert 40.0 <= lo < terrain[0] and terrain[1] < hi <= 1090.0
    assert hi - lo < 0.4 * (1090.0 - 40.0)
    frac, n_on_dsm, median_dh = true_fraction(
        ties, dsm_heights(ties.ground, folder / "expected_dsm.tif"), 5.0
    )
    # measured: 7643 ties, 3512 on the DSM, 97.3 % within 5 m, median -2.4 m (the pair's
    # uncorrected relative pointing; s2p's README: -1.9 m on its own 481 ties)
    assert len(ties) > 5000 and n_on_dsm > 2000
    assert frac >= 0.9
    assert -4.0 < median_dh < -1.0
    assert rep.rejected["duplicate"] > 0  # SIFT's orientations, collapsed
    assert (
        abs(rep.across_px - (-0.68)) < 0.1
    )  # as s2p's own ties imply (tests/stereo/test_matching)


@pytest.fixture(scope="module")
def ventoux(real_data):
    folder = real_data / "ventoux"
    left = open_image(folder / "left_image.tif", model=real_data / "phr_ventoux__left_image.geom")
    right = open_image(
        folder / "right_image.tif", model=real_data / "phr_ventoux__right_image.geom"
    )
    dem = read_dem(
        folder / "dem" / "N44E005_srtm90.tif",
        height="orthometric",
        geoid=folder / "dem" / "egm96_15_crop_lon3-8_lat42-47.gtx",
    )
    features = [sift_features_raster(im.path) for im in (left, right)]
    return left, right, dem, features


@pytest.mark.parametrize("use_dem", [False, True], ids=["coarse", "dem"])
def test_ventoux_crops_true_against_srtm(ventoux, use_dem):
    left, right, dem, (f1, f2) = ventoux
    assert left.origin == (5000.0, 5000.0)  # a crop: its model is the full product's
    ties = tie_points(
        left.model, right.model, left.path, right.path, dem=dem if use_dem else None,
        features1=f1, features2=f2,
    )  # fmt: skip
    rep = ties.report
    check_bookkeeping(ties)
    assert rep.height_source == ("dem" if use_dem else "coarse matching")
    srtm = dem(ties.ground[:, :2])
    if use_dem:  # SRTM over the footprint +- 50 m
        assert rep.height_range_m[0] < srtm.min() - 40 and rep.height_range_m[1] > srtm.max() + 40
    frac, n, median_dh = true_fraction(ties, srtm, 20.0)
    # measured: ~700 ties, 100 % within 20 m of SRTM, median +3.7 m; the relative bias across
    # the epipolar curves is -4.75 px (larger than the triplet's)
    assert n == len(ties) > 400
    assert frac >= 0.9 and abs(median_dh) < 10.0
    assert abs(rep.across_px - (-4.75)) < 0.3


def test_validity_heights(shared_data, real_data):
    im = open_image(shared_data / "s2p_triplet" / "img_01.tif")
    assert validity_heights(im.model) == (40.0, 1090.0)  # h_off 565 +- h_scale 525
    biased = Biased(im.model, ShiftBias((3.0, -2.0)))
    assert validity_heights(biased) == (40.0, 1090.0)


def write_dem(path, heights, west, north, step):
    with rasterio.open(
        path, "w", driver="GTiff", width=heights.shape[1], height=heights.shape[0], count=1,
        dtype="float32", crs="EPSG:4326", transform=from_origin(west, north, step, step),
    ) as dst:  # fmt: skip
        dst.write(heights.astype("float32")[None])
    return path


def test_bad_requests_are_named_errors(ventoux, tmp_path):
    left, right, _, _ = ventoux
    args = (left.model, right.model, left.path, right.path)
    with pytest.raises(TieError, match="HMIN < HMAX"):
        tie_points(*args, MatchSettings(height_range_m=(900.0, 500.0)))
    with pytest.raises(TieError, match="HMIN < HMAX"):
        tie_points(*args, MatchSettings(height_range_m=(float("nan"), 500.0)))
    with pytest.raises(TieError, match=r"not inside .*left_image.tif \(500 x 500 px\)"):
        tie_points(*args, MatchSettings(roi=(450, 0, 100, 100)))
    with pytest.raises(TieError, match="tolerance"):
        tie_points(*args, MatchSettings(epipolar_tol_px=0.0))
    # a DEM 4 km up: outside the models' validity range (190..1960 m), named
    lon, lat = (
        float(v) for v in np.asarray(left.model.localize(np.array([250.0, 250.0]), 500.0))[:2]
    )
    dem_path = write_dem(tmp_path / "high.tif", np.full((20, 20), 4000.0), lon - 0.05, lat + 0.05,
                         0.005)  # fmt: skip
    with pytest.raises(TieError, match=r"high.tif: its heights .* outside the models' validity"):
        tie_points(*args, dem=read_dem(dem_path))


def test_join_ties_makes_multi_image_points():
    p = np.array([[10.0, 20.0], [30.0, 40.0], [50.0, 60.0], [70.0, 80.0]])
    pairs = [
        # image 0 - 1: keypoints 0, 1, 2 of image 0
        (0, 1, p[:3], p[:3] + 1),
        # image 0 - 2: keypoint 0 again (-> a 3-image point), keypoint 3 (a 2-image point)
        (0, 2, p[[0, 3]], p[[0, 3]] + 2),
        # image 1 - 2: closes the triangle of keypoint 0; keypoint 1 of image 1 reaches a point
        # of image 2 that keypoint 1 of image 0 does not: consistent (no image twice) -> 3 views;
        # keypoint 2 of image 1 meets two positions of image 2 -> inconsistent, dropped
        (1, 2, p[:3] + 1, np.array([[12.0, 22.0], [33.0, 43.0], [99.0, 99.0]])),
        (1, 2, p[2:3] + 1, np.array([[98.0, 98.0]])),
    ]
    joined = join_ties(pairs)
    assert joined.n_conflicting == 1
    assert sorted(joined.n_views.tolist()) == [2, 3, 3]
    assert len(joined.point) == joined.n_views.sum() == len(joined.image) == len(joined.xy)
    for k in range(len(joined.n_views)):
        images = joined.image[joined.point == k]
        assert len(set(images.tolist())) == len(images)  # one observation per image
    first = joined.xy[joined.point == joined.point[0]]
    np.testing.assert_allclose(first, [[10, 20], [11, 21], [12, 22]])
    empty = join_ties([])
    assert len(empty.point) == 0 and empty.n_conflicting == 0


def test_a_few_strongest_keypoints_give_the_same_ties_on_the_s2p_triplet(shared_data):
    """``MatchSettings(keypoints=...)`` (what a DSM tile and the plan's height search use): the
    strongest 1500 keypoints of image 1 (image 2's window as many per pixel) still give true
    ties, hundreds of them, and the same relative bias across the epipolar curves and the same
    height range as all of them (test above: -0.68 px)."""
    folder = shared_data / "s2p_triplet"
    im1, im2 = open_image(folder / "img_01.tif"), open_image(folder / "img_02.tif")
    ties = tie_points(im1.model, im2.model, im1.path, im2.path, MatchSettings(keypoints=1500))
    rep = ties.report
    check_bookkeeping(ties)
    # measured: 1500 / 1530 keypoints of 15132 / 14702, 631 ties (256 on the DSM, 98.8 % within
    # 5 m, median -2.27 m), across -0.688 px (-0.684 with all); range 40..347 m (40..361 m)
    assert rep.n_keypoints[0] <= 1500 * 1.05 and len(ties) > 400
    frac, n_on_dsm, median_dh = true_fraction(
        ties, dsm_heights(ties.ground, folder / "expected_dsm.tif"), 5.0
    )
    assert n_on_dsm > 200 and frac >= 0.9 and -4.0 < median_dh < -1.0
    assert abs(rep.across_px - (-0.68)) < 0.1
    with rasterio.open(folder / "expected_dsm.tif") as src:
        terrain = np.nanpercentile(src.read(1), [1, 99])
    lo, hi = rep.height_range_m
    assert lo < terrain[0] and terrain[1] < hi


def test_keypoints_must_be_a_positive_count():
    for bad in (0, -5):
        with pytest.raises(TieError, match="keypoints"):
            MatchSettings(keypoints=bad)
    assert MatchSettings(keypoints=500).keypoints == 500 and MatchSettings().keypoints is None
