"""Resampling, semi-global matching and DSM rasterisation on synthetic inputs (fast)."""

import numpy as np
import pytest
import rasterio

from jaxgeo.stereo import rasterize, sgm_disparity, write_dsm
from jaxgeo.stereo._dense import refine_disparity, resample_epipolar
from jaxgeo.stereo._dsm import to_map
from jaxgeo.stereo._matching import to_uint8
from jaxgeo.stereo._rectification import EpipolarGrids, node_xy


def _texture(rows, cols, seed=0):
    import cv2

    noise = np.random.default_rng(seed).normal(size=(rows, cols)).astype(np.float32)
    return cv2.GaussianBlur(noise, (0, 0), 1.2)


def test_resample_through_identity_grid_shifted():
    img = _texture(90, 120)
    nodes = node_xy((5, 6), 30.0)
    grids = EpipolarGrids(nodes + (3.0, 2.0), nodes, 30.0, (60, 80), np.nan, np.zeros((5, 6)))
    left = resample_epipolar(img, grids, "left", interpolation="linear")
    np.testing.assert_allclose(left, img[2:62, 3:83], atol=1e-5)
    # sampling across the epipolar lines moves rows; outside the image is NaN
    right = resample_epipolar(img, grids, "right", y_shift_px=1.0, interpolation="linear")
    np.testing.assert_allclose(right[:59], img[1:60, :80], atol=1e-5)
    # a window starting at sensor x = 60: epipolar columns left of it have no data
    window = resample_epipolar(
        img[:, 60:], grids, "left", origin_xy=(60.0, 0.0), interpolation="linear"
    )
    assert np.isnan(window[:, :57]).all()
    np.testing.assert_allclose(window[:, 57:], img[2:62, 60:83], atol=1e-5)


def test_sgm_recovers_a_known_disparity():
    rows, cols, d = 120, 200, -7
    big = _texture(rows, cols + 20)
    left = big[:, 10 : 10 + cols]
    right = big[:, 10 - d : 10 - d + cols]  # right(xe + d) = left(xe)
    lims = (float(big.min()), float(big.max()))
    disp = sgm_disparity(to_uint8(left, lims), to_uint8(right, lims), -12.0, 2.0)
    core = disp[:, 30:-30]
    assert np.isfinite(core).mean() > 0.9
    assert np.nanmedian(core) == pytest.approx(d, abs=0.1)
    assert np.nanpercentile(np.abs(core - d), 95) < 0.5


def test_resample_with_an_affine_shift_across_the_lines():
    img = _texture(90, 120)
    nodes = node_xy((5, 6), 30.0)
    grids = EpipolarGrids(nodes, nodes, 30.0, (60, 80), np.nan, np.zeros((5, 6)))
    shift = (1.0, 0.01, -0.02)  # a + b_x xe + b_y ye
    right = resample_epipolar(img, grids, "right", y_shift_px=shift, interpolation="linear")
    ye, xe = np.mgrid[0:60, 0:80].astype(float)
    y = ye + 1.0 + 0.01 * xe - 0.02 * ye
    y0 = np.floor(y).astype(int)
    f = y - y0
    expect = img[y0, xe.astype(int)] * (1 - f) + img[y0 + 1, xe.astype(int)] * f
    np.testing.assert_allclose(right, expect, atol=1e-4)
    # a constant is the affine shift (a, 0, 0)
    np.testing.assert_array_equal(
        resample_epipolar(img, grids, "right", y_shift_px=0.4),
        resample_epipolar(img, grids, "right", y_shift_px=(0.4, 0.0, 0.0)),
    )


@pytest.mark.parametrize("d", [-7.25, -7.5, -6.8])
def test_refinement_removes_the_pixel_locking_of_sgbm(d):
    """OpenCV's parabola fit pulls disparities towards whole pixels; the correlation refinement
    finds the sub-pixel shift (a band-limited texture shifted in Fourier space)."""
    rows, cols = 100, 220
    left = _texture(rows, cols, seed=3)
    k = np.fft.fftfreq(cols)
    right = np.real(np.fft.ifft(np.fft.fft(left, axis=1) * np.exp(-2j * np.pi * k * d), axis=1))
    right = right.astype(np.float32)  # right(x + d) = left(x)
    lims = (float(left.min()), float(left.max()))
    sgm = sgm_disparity(to_uint8(left, lims), to_uint8(right, lims), -12.0, 2.0)
    refined = refine_disparity(left, right, sgm)
    core = (slice(10, -10), slice(30, -30))
    err_sgm, err = np.abs(sgm[core] - d), np.abs(refined[core] - d)
    assert np.isfinite(refined[core]).mean() > 0.9
    assert np.nanmedian(err) < 0.03 and np.nanpercentile(err, 90) < 0.1
    assert np.nanmedian(err_sgm) > 0.05  # what the refinement fixes
    # no data in the window: SGBM's value is kept
    holed = left.copy()
    holed[40:60, 100:120] = np.nan
    again = refine_disparity(holed, right, sgm)
    np.testing.assert_array_equal(again[48:52, 108:112], sgm[48:52, 108:112])


def test_rasterize_median_count_spread_and_gaps(tmp_path):
    lon0, lat0 = 5.3, 43.3
    rng = np.random.default_rng(1)
    pts = np.stack(
        [lon0 + rng.uniform(0, 2e-4, 4000), lat0 + rng.uniform(0, 2e-4, 4000), np.zeros(4000)],
        axis=1,
    )
    xy = to_map(pts, 32631)
    pts[:, 2] = 100.0 + 0.1 * (xy[:, 0] - xy[:, 0].min())  # a plane rising 10 cm per metre east
    pts[::10, 2] += 50.0  # 10 % outliers: the median ignores them
    dsm = rasterize(pts, 2.0, footprint_m=0.0, max_hole_m=0.0)  # each point in its cell only
    assert dsm.epsg == 32631
    filled = np.isfinite(dsm.height)
    assert filled.mean() > 0.8 and dsm.count[filled].min() >= 1
    assert dsm.count.sum() == 4000 and not np.any(dsm.count[~filled])
    cols = np.arange(dsm.height.shape[1]) * 2.0 + dsm.x0 + 1.0 - xy[:, 0].min()
    expect = 100.0 + 0.1 * np.broadcast_to(cols, dsm.height.shape)
    dense = filled & (dsm.count >= 8)
    assert np.abs(dsm.height - expect)[dense].max() < 0.2 + 1e-9
    assert np.nanmax(dsm.spread) > 5  # the outliers show in the spread band
    out = write_dsm(dsm, tmp_path / "dsm.tif")
    with rasterio.open(out) as f:
        assert f.count == 5 and f.crs.to_epsg() == 32631 and f.profile["tiled"]
        np.testing.assert_array_equal(f.read(1), dsm.height)
    with pytest.raises(FileExistsError):
        write_dsm(dsm, out)


def test_a_band_without_matches_triangulates_to_no_point():
    """A ROI's epipolar rows may hold no match (a 1000 px ROI of a 2000 px scene failed with a
    TypeError from jax.tree.map): no point, no triangulation."""
    from jaxgeo.stereo._triangulation import triangulate_disparities

    points, sigma = triangulate_disparities((), None, np.zeros((0, 3)), np.zeros((0, 2, 2)))
    assert points.shape == (0, 3) and sigma.shape == (0,)
