"""What makes a DSM tile cheap, and keeps it exact: the dense triangulation's lattice
(``disparity_lattice``: points interpolated between exactly triangulated epipolar nodes) equals
the point-by-point intersection to well under a millimetre and falls back to it where it cannot
answer, and so do the height sigmas from its interpolated Jacobian; the grids' blocked and mesh
interpolation equal the plain bilinear one; the stage clock of a tile; the sampled point
spacing; the keypoints of a half-resolution SIFT in full-resolution pixels; the reference window
read and searched once per tile.

Scene: :func:`jaxgeo.simulate.stereo_scene`, 300 x 300 px, seed 5, exact RPCs."""

import numpy as np
import pytest

from jaxgeo.io import open_image
from jaxgeo.simulate import StereoSceneSettings, stereo_scene
from jaxgeo.stereo import epipolar_grids
from jaxgeo.stereo._dsm import point_spacing
from jaxgeo.stereo._rectification import _bilinear, interpolate_grid, interpolate_mesh
from jaxgeo.stereo._stages import STAGES, StageTimes, stage
from jaxgeo.stereo._triangulation import (
    JACOBIAN_TOL,
    LATTICE_TOL_M,
    disparity_lattice,
    triangulate_disparities,
)
from jaxgeo.stereo._triangulation import _exact as exact_triangulation  # one compiled shape
from jaxgeo.stereo._uncertainty import a_priori_orientation, point_height_sigmas


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scene")
    stereo_scene(folder, 300, 5, StereoSceneSettings(exact_rpc=True))
    images = [open_image(folder / name) for name in ("left.tif", "right.tif")]
    models = [im.model for im in images]
    h0 = float(np.asarray(models[0].reference_ground())[2])
    grids = epipolar_grids(*models, (0, 0, 300, 300), elevation=h0, epi_step=30)
    return models, grids


def _right(shift):
    return lambda xe, ye: np.stack([xe, ye + shift], axis=-1)


def _matches(grids, epi, shift):
    left = grids.to_sensor("left", epi[:, :2])
    right = grids.to_sensor("right", _right(shift)(epi[:, 0] + epi[:, 2], epi[:, 1]))
    return np.stack([left, right], axis=1)


def _random_epipolar(grids, n, d_range, seed=0):
    rows, cols = grids.epipolar_shape
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0, cols - 1, n), rng.uniform(0, rows - 1, n),
                            rng.uniform(*d_range, n)])  # fmt: skip


def test_the_lattice_equals_the_exact_intersection(pair):
    models, grids = pair
    shift = 0.3  # a vertical disparity removed: the right points sampled off the lines
    rows, cols = grids.epipolar_shape
    lattice = disparity_lattice(models, grids, _right(shift), (0, cols, 0, rows), (-20.0, 25.0))
    assert lattice.usable and lattice.check_error_m < 0.1 * LATTICE_TOL_M
    epi = _random_epipolar(grids, 5000, (-20.0, 25.0))
    matches = _matches(grids, epi, shift)
    points, sigma = triangulate_disparities(models, lattice, epi, matches)
    exact, exact_sigma = exact_triangulation(models, matches, "intersect")
    per_deg = 111_320.0 * np.array([np.cos(np.radians(exact[0, 1])), 1.0])  # m per degree
    dlon, dlat, dh = np.abs(points - exact).max(axis=0)
    assert dlon * per_deg[0] < 1e-3 and dlat * per_deg[1] < 1e-3 and dh < 1e-3
    np.testing.assert_allclose(sigma, exact_sigma, rtol=1e-3)
    assert np.all(np.isfinite(points))


def test_points_the_lattice_cannot_answer_are_triangulated_one_by_one(pair):
    models, grids = pair
    rows, cols = grids.epipolar_shape
    lattice = disparity_lattice(models, grids, _right(0.0), (0, cols, 0, rows), (-10.0, 10.0))
    epi = _random_epipolar(grids, 200, (-10.0, 10.0), seed=1)
    epi[:20, 2] = 40.0  # disparities outside the lattice
    lattice.values[1, 1, 1, :] = np.nan  # a node without a point
    matches = _matches(grids, epi, 0.0)
    exact, _ = exact_triangulation(models, matches, "intersect")
    points, _ = triangulate_disparities(models, lattice, epi, matches)
    assert np.isnan(lattice.interpolate(epi[:20, 0], epi[:20, 1], epi[:20, 2])).all()
    np.testing.assert_allclose(points, exact, atol=1e-7)
    # the matches made on demand (the pipeline's), only for the points the lattice lacks
    asked = []
    lazy, _ = triangulate_disparities(
        models, lattice, epi, lambda rows: asked.append(rows) or matches[rows]
    )
    np.testing.assert_array_equal(lazy, points)
    assert len(np.concatenate(asked)) < 40 and set(range(20)) <= set(np.concatenate(asked))
    # a lattice failing its check is not used at all: every point on its own
    import dataclasses

    failed = dataclasses.replace(lattice, check_error_m=2 * LATTICE_TOL_M)
    assert not failed.usable
    points, _ = triangulate_disparities(models, failed, epi, matches)
    np.testing.assert_allclose(points, exact, atol=1e-9)


def test_the_sigmas_from_the_lattice_jacobian_equal_the_point_by_point_ones(pair):
    """The height sigmas (matching and orientation) with ``d up / d xy`` interpolated in the
    lattice equal those of a ``jacfwd`` per point to 0.1 %; a point the lattice cannot answer,
    or a lattice whose Jacobian check fails, takes the per-point Jacobian."""
    import dataclasses

    models, grids = pair
    shift = 0.3
    rows, cols = grids.epipolar_shape
    lattice = disparity_lattice(models, grids, _right(shift), (0, cols, 0, rows), (-20.0, 25.0))
    assert lattice.jacobian_usable and lattice.jacobian_check_error < 0.1 * JACOBIAN_TOL
    epi = _random_epipolar(grids, 3000, (-20.0, 25.0), seed=4)
    epi[:10, 2] = 60.0  # outside the lattice: NaN Jacobian, computed per point
    matches = _matches(grids, epi, shift)
    points, _, up = triangulate_disparities(models, lattice, epi, matches, up_jacobian=True)
    assert np.isnan(up[:10]).all() and np.isfinite(up[10:]).all()
    points[20] = np.nan  # a dropped point: no sigma
    rng = np.random.default_rng(5)
    direction, sigma_d = rng.normal(size=(len(epi), 2)), rng.uniform(0.1, 0.5, len(epi))
    orientation = a_priori_orientation(2)
    fast = point_height_sigmas(models, points, direction, sigma_d, orientation, up_jacobian=up)
    slow = point_height_sigmas(models, points, direction, sigma_d, orientation)
    for got, want in zip(fast, slow, strict=True):
        assert np.isnan(got[20]) and np.isnan(want[20])
        np.testing.assert_allclose(got, want, rtol=1e-3)
        np.testing.assert_array_equal(got[:10], want[:10])  # the fallback is the same call
    failed = dataclasses.replace(lattice, jacobian_check_error=2 * JACOBIAN_TOL)
    assert failed.usable and not failed.jacobian_usable
    assert np.isnan(
        triangulate_disparities(models, failed, epi, matches, up_jacobian=True)[2]
    ).all()


def test_the_lattice_interpolation_is_trilinear():
    """One pass over every channel equals ``map_coordinates`` of each channel (order 1): inside,
    on the upper faces, NaN outside, NaN next to a node without a value."""
    from scipy.ndimage import map_coordinates

    from jaxgeo.stereo._triangulation import LATTICE_BLOCK, DisparityLattice

    rng = np.random.default_rng(6)
    values = rng.normal(size=(4, 5, 6, 8))
    lattice = DisparityLattice((10.0, -30.0, -7.5), (30.0, 30.0, 15.0), np.zeros(3), values, 0.0)
    n = LATTICE_BLOCK + 500  # two blocks
    d = rng.uniform(-7.5, 37.5, n)
    ye, xe = rng.uniform(-30.0, 90.0, n), rng.uniform(10.0, 160.0, n)
    d[:3], ye[3:6], xe[6:9] = 37.5, 90.0, 160.0  # the upper faces
    got = lattice.interpolate(xe, ye, d)
    coords = np.stack([(d + 7.5) / 15.0, (ye + 30.0) / 30.0, (xe - 10.0) / 30.0])
    want = np.stack([map_coordinates(values[..., k], coords, order=1, prefilter=False)
                     for k in range(8)], axis=-1)  # fmt: skip
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    outside = lattice.interpolate(
        np.array([9.0, 50.0]), np.array([0.0, 0.0]), np.array([0.0, 38.0])
    )
    assert np.isnan(outside).all()
    values[1, 1, 1, 2] = np.nan
    near = lattice.interpolate(np.array([40.0 + 5, 200.0 - 60]), np.array([5.0, 5.0]),
                               np.array([10.0, 10.0]))  # fmt: skip
    assert np.isnan(near[0, 2]) and np.isfinite(near[0, [0, 1, 3]]).all()
    assert np.isfinite(near[1]).all()


def test_the_blocked_and_mesh_grid_interpolation_equal_the_plain_one(pair):
    """:func:`interpolate_grid` in blocks and :func:`interpolate_mesh` (row blocks, a vertical
    shift affine in ``xe`` and ``ye``, an origin, float32 maps) give the plain bilinear values."""
    _, grids = pair
    xs, ys = np.arange(-40.0, 340.0), np.arange(-5.0, 310.0)
    xe, ye = np.meshgrid(xs, ys)
    shift = (0.4, 2e-3, -1e-3)  # crosses node rows along the lines
    y_of = lambda x, y: y + shift[0] + shift[1] * x + shift[2] * y  # noqa: E731
    pts = np.stack([xe, y_of(xe, ye)], axis=-1)
    plain = _bilinear(grids.right, grids.step_px, pts.reshape(-1, 2))
    value, along = interpolate_grid(grids.right, grids.step_px, pts, along=True)
    np.testing.assert_array_equal(value.reshape(-1, 2), plain[0])
    np.testing.assert_array_equal(along.reshape(-1, 2), plain[1])
    origin = (12.0, -7.0)
    mesh = interpolate_mesh(grids.right, grids.step_px, xs, ys, y_of, origin, np.float32)
    assert mesh.shape == (*xe.shape, 2) and mesh.dtype == np.float32
    np.testing.assert_array_equal(mesh, (plain[0] - origin).astype(np.float32).reshape(mesh.shape))
    left = grids.mesh_to_sensor("left", xs, ys)
    np.testing.assert_array_equal(left, grids.to_sensor("left", np.stack([xe, ye], axis=-1)))


def test_stage_times_are_kept_only_while_a_clock_is_active():
    with stage("sgm"):  # no clock: nothing kept, nothing raised
        pass
    with StageTimes() as times:
        for _ in range(2):
            with stage("sgm"):
                sum(range(100_000))
        with stage("extra"):
            pass
    with stage("sgm"):  # after the clock: not counted
        sum(range(100_000))
    out = times.as_dict()
    assert list(out) == ["sgm", "extra"] and "sgm" in STAGES
    assert out["sgm"]["wall_s"] > 0 and out["sgm"]["cpu_s"] > 0


def test_the_sampled_point_spacing_is_the_whole_ones():
    """Over a million points the spacing comes from a central square of them: the same median
    nearest-neighbour distance as the tree of all of them (a jittered 0.7 m lattice)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    g = np.mgrid[0:1000, 0:1000].reshape(2, -1).T * 0.7
    xy = g + rng.normal(scale=0.15, size=g.shape)
    whole = float(np.median(cKDTree(xy).query(xy[::50], k=2)[0][:, 1]))
    assert point_spacing(xy) == pytest.approx(whole, rel=0.02)
    assert point_spacing(xy[:5000]) > 0


def test_half_resolution_keypoints_are_in_full_resolution_pixels(tmp_path):
    """The same texture at full and half resolution: the coarse keypoints, carried to the full
    image's pixels, lie on the full ones (no stretch of the scale with an odd size, no shift
    beyond SIFT's own quarter pixel)."""
    import cv2
    from scipy.spatial import cKDTree

    from jaxgeo.stereo._keypoints import SIFT_COARSE_MIN_PX, window_keypoints

    rng = np.random.default_rng(2)
    size = SIFT_COARSE_MIN_PX + 33  # odd: whole 2 x 2 blocks only
    image = cv2.GaussianBlur(rng.normal(size=(size, size)).astype(np.float32), (0, 0), 3.0)
    coarse, _ = window_keypoints(image, (100, 50), (-0.05, 0.05))
    from jaxgeo.stereo import sift_features
    from jaxgeo.stereo._matching import to_uint8

    full, _ = sift_features(to_uint8(image, (-0.05, 0.05)))
    full = full + (100, 50)
    dist, idx = cKDTree(full).query(coarse)
    near = dist < 1.5
    assert near.sum() > 200
    offset = coarse[near] - full[idx[near]]
    assert np.all(np.abs(np.median(offset, axis=0)) < 0.35)
    # the same offset at both ends of the image: no drift of the scale
    left = coarse[near][:, 0] < size / 2 + 100
    drift = np.median(offset[left], axis=0) - np.median(offset[~left], axis=0)
    assert np.all(np.abs(drift) < 0.1)


def test_the_reference_window_is_read_and_searched_once_per_tile(tmp_path):
    """The pairs of a tile share the reference's window: read and searched once; another window,
    or the file rewritten, is read again."""
    import os

    from jaxgeo.stereo._keypoints import reference_features

    path = tmp_path / "ref.tif"
    path.write_bytes(b"x")
    reads = []
    rng = np.random.default_rng(3)

    def read(p, window):
        reads.append(window)
        return rng.normal(size=(window[3], window[2])).astype(np.float32)

    a = reference_features(path, (0, 0, 120, 100), read, 500)
    b = reference_features(path, (0, 0, 120, 100), read, 500)
    assert len(reads) == 1 and b is a and len(a[2][0]) > 0
    reference_features(path, (10, 0, 120, 100), read, 500)
    assert len(reads) == 2
    st = os.stat(path)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    reference_features(path, (10, 0, 120, 100), read, 500)
    assert len(reads) == 3


def test_capped_keypoints_are_spread_over_the_image():
    """``sift_features(..., most=n)``: about ``n`` keypoints, the strongest of each cell of a grid
    in turn, so a quarter of the image with four times the contrast does not take them all (the
    strongest of all would cluster there; a rectification needs ties everywhere)."""
    import cv2

    from jaxgeo.stereo import sift_features
    from jaxgeo.stereo._matching import to_uint8

    rng = np.random.default_rng(4)
    image = cv2.GaussianBlur(rng.normal(size=(400, 400)).astype(np.float32), (0, 0), 2.0)
    image[:200, :200] *= 4.0
    image8 = to_uint8(image, (-0.6, 0.6))
    every, _ = sift_features(image8)
    xy, desc = sift_features(image8, most=400)
    assert len(every) > 1000 and 390 <= len(xy) <= 400 and desc.shape == (len(xy), 128)
    weak = ~((xy[:, 0] < 200) & (xy[:, 1] < 200))
    assert weak.mean() > 0.6  # three quarters of the area, three quarters of the keypoints
    # each kept keypoint is one of the full detection's (same place)
    from scipy.spatial import cKDTree

    assert np.all(cKDTree(every).query(xy)[0] < 1e-6)


def test_the_mesh_in_a_window_equals_each_pixel_mapped(pair):
    """``EpipolarGrids.mesh_in_window`` (grid cells decided by their nodes, the rest mapped) is
    the pixel-by-pixel test of :meth:`mesh_to_sensor`, windows cutting cells and the mesh
    reaching beyond the nodes (extrapolated columns) included."""
    _, grids = pair
    rows, cols = grids.epipolar_shape
    xs, ys = np.arange(-40, cols + 40, dtype=float), np.arange(-5, rows + 5, dtype=float)
    sensor = grids.mesh_to_sensor("left", xs, ys)
    decided = 0
    for window in ((37, 21, 200, 230), (0, 0, 300, 300), (120, -10, 17, 400), (400, 0, 50, 50)):
        col, row, w, h = window
        want = ((sensor[..., 0] >= col - 0.5) & (sensor[..., 0] < col + w - 0.5)
                & (sensor[..., 1] >= row - 0.5) & (sensor[..., 1] < row + h - 0.5))  # fmt: skip
        got = grids.mesh_in_window("left", xs, ys, window)
        assert np.array_equal(got, want), window
        decided += want.any() and not want.all()
    assert decided >= 2  # windows cutting the mesh, not only all in or all out
