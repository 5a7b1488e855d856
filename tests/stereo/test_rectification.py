"""Epipolar grids and triangulation against OTB, shareloc and CARS on the Ventoux Pleiades pair
(values and tolerances from ``tests/data/real/ventoux/reference_values.json``)."""

import json

import numpy as np
import pytest
import rasterio

from jaxgeo.io import read_rpc
from jaxgeo.stereo import epipolar_grids, triangulate
from jaxgeo.stereo._rectification import EpipolarGrids
from jaxgeo.stereo._triangulation import disparity_to_matches

LEFT_WINDOW = (5000, 5000, 500, 500)  # left_image.tif: geotransform origin (5000, 5000)


@pytest.fixture(scope="module")
def ventoux(real_data):
    left = read_rpc(real_data / "phr_ventoux__left_image.geom")
    right = read_rpc(real_data / "phr_ventoux__right_image.geom")
    refs = json.loads((real_data / "ventoux" / "reference_values.json").read_text())
    return left, right, real_data / "ventoux", refs


def _grid(path):
    with rasterio.open(path) as f:
        return np.stack([f.read(1), f.read(2)], axis=-1).astype(float)


def _ref(refs, key, ident):
    return next(r for r in refs[key] if r["id"] == ident)


@pytest.fixture(scope="module")
def grids0(ventoux):
    left, right, _, _ = ventoux
    return epipolar_grids(left, right, LEFT_WINDOW, elevation=0.0, epi_step=30)


def test_grids_match_otb_and_shareloc(ventoux, grids0):
    _, _, folder, refs = ventoux
    case = _ref(refs, "epipolar_rectification", "rpc_elev0")["expect"]
    assert list(grids0.epipolar_shape) == case["rectified_image_size_rows_cols"]
    assert list(grids0.left.shape[:2]) == case["grid_nodes_rows_cols"]
    for side in ("left", "right"):
        otb = _grid(folder / case["grids_vs_OTB"][side].removeprefix("ventoux/"))
        assert np.abs(grids0.displacement(side) - otb).max() < case["grids_vs_OTB"]["tol_px"]
        # shareloc's own regression grids: 2e-10 / 1.6e-9 px here (localisation convergence)
        gt = _grid(folder / case["grids_vs_shareloc_regression"][side].removeprefix("ventoux/"))
        assert np.abs(grids0.displacement(side) - gt).max() < 1e-8
    br = grids0.mean_baseline_ratio
    assert abs(br - case["mean_baseline_ratio_OTB"]) < case["mean_baseline_ratio_OTB_tol"]
    assert abs(br - case["mean_baseline_ratio_shareloc"]) < 1e-11
    first = _ref(refs, "epipolar_rectification", "prepare_rectification")["expect"]
    col_row = first["first_epipolar_point_in_left_image_OTB_col_row_h"][:2]
    np.testing.assert_allclose(grids0.left[0, 0] + 0.5, col_row, atol=first["first_point_tol_px"])


def test_grids_at_100m_match_otb(ventoux):
    left, right, folder, refs = ventoux
    case = _ref(refs, "epipolar_rectification", "rpc_elev100")["expect"]
    g = epipolar_grids(left, right, LEFT_WINDOW, elevation=100.0, epi_step=30)
    for side in ("left", "right"):
        otb = _grid(folder / case["grids_vs_OTB"][side].removeprefix("ventoux/"))
        assert np.abs(g.displacement(side) - otb).max() < case["grids_vs_OTB"]["tol_px"]
    assert abs(g.mean_baseline_ratio - case["mean_baseline_ratio_OTB"]) < 1e-5


def test_grid_extrapolation(ventoux):
    _, _, folder, refs = ventoux
    case = _ref(refs, "epipolar_rectification", "grid_extrapolation")
    g = _grid(folder / "epipolar_grids" / "left_epipolar_grid_ventoux.tif")
    grids = EpipolarGrids.from_displacement(g, g, 30, (612, 612))
    rows = grids.to_sensor("left", np.array(case["inputs"]["epipolar_col_row"]))[:, 1] + 0.5
    np.testing.assert_allclose(rows, case["expect"]["sensor_row"], atol=1e-10, rtol=0)


def test_triangulation_matches_cars(ventoux):
    left, right, folder, refs = ventoux
    case = _ref(refs, "triangulation", "epi_triangulation_disp_rpc_roi")["expect"]
    grids = EpipolarGrids.from_displacement(
        _grid(folder / "epipolar_grids" / "left_epipolar_grid_ventoux.tif"),
        _grid(folder / "epipolar_grids" / "right_epipolar_grid_ventoux.tif"),
        30,
        (612, 612),
    )
    disp = np.load(folder / "triangulation" / "disp1_ref.npz")
    ref = np.load(folder / "triangulation" / "triangulation1_ref.npz")
    xl, xr = disparity_to_matches(grids, disp["disp"], int(disp["row"][0]), int(disp["col"][0]))
    pts = np.stack([xl, xr], axis=-2).reshape(-1, 2, 2)
    ground, _ = triangulate([left, right], pts, method="los_midpoint")
    valid = disp["msk"].ravel() == 255
    assert np.isnan(ground[~valid]).all() and valid.sum() == 13174
    for k, name in enumerate(("lon", "lat", "h")):
        diff = np.abs(ground[valid, k] - ref[name].ravel()[valid])
        assert diff.max() < (1e-8 if k < 2 else 1e-3), (name, diff.max())
    at100 = case["flat_index_100_lon_lat_h"]
    np.testing.assert_allclose(ground[100, :2], at100[:2], atol=1e-8, rtol=0)
    assert abs(ground[100, 2] - case["flat_index_100_lon_lat_h"][2]) < case["tol"][2]
    # jaxgeo's image-space intersection (method="intersect") differs from this chord midpoint by
    # the rays' miss: +4.5 cm median in height (relative bias of the pair); not run here (a
    # 40 s compile of the vmapped Gauss-Newton), measured in the closing notes of issue 13.


def test_grids_of_a_biased_model(ventoux, grids0):
    """Any model works: an RPC + image shift as the right model moves the right grid by the
    shift and leaves the left grid (the epipolar geometry in the left image) unchanged."""
    from jaxgeo.models import Biased, ShiftBias

    left, right, _, _ = ventoux
    biased = Biased(right, ShiftBias((1.25, -0.75)))  # measured = model - shift
    g = epipolar_grids(left, biased, LEFT_WINDOW, elevation=0.0, epi_step=30)
    np.testing.assert_allclose(g.left, grids0.left, atol=1e-8, rtol=0)
    np.testing.assert_allclose(
        g.right - grids0.right, np.broadcast_to([-1.25, 0.75], g.right.shape), atol=1e-8
    )
    assert g.epipolar_shape == grids0.epipolar_shape


def test_to_epipolar_inverts_to_sensor(ventoux, grids0):
    """Sensor -> epipolar (Newton on the bilinear grid) is the inverse of epipolar -> sensor,
    inside the nodes and in the extrapolated border, both sides; NaN stays NaN."""
    rng = np.random.default_rng(3)
    rows, cols = grids0.epipolar_shape
    epi = np.column_stack([rng.uniform(-40, cols + 40, 2000), rng.uniform(-40, rows + 40, 2000)])
    epi[5] = np.nan
    for side in ("left", "right"):
        back = grids0.to_epipolar(side, grids0.to_sensor(side, epi))
        assert np.isnan(back[5]).all()
        np.testing.assert_allclose(np.delete(back, 5, 0), np.delete(epi, 5, 0), atol=1e-8)


def test_along_is_the_derivative_along_the_lines(grids0):
    """The sensor step per epipolar pixel along the lines: the bilinear grid's x derivative
    (central differences inside a cell agree to rounding)."""
    rng = np.random.default_rng(4)
    rows, cols = grids0.epipolar_shape
    epi = np.column_stack([rng.uniform(0, cols, 500), rng.uniform(0, rows, 500)])
    epi[:, 0] = np.floor(epi[:, 0] / 30) * 30 + 15  # cell centres: differences stay in a cell
    value, step = grids0.along("right", epi)
    np.testing.assert_array_equal(value, grids0.to_sensor("right", epi))
    fd = grids0.to_sensor("right", epi + [0.5, 0]) - grids0.to_sensor("right", epi - [0.5, 0])
    np.testing.assert_allclose(step, fd, atol=1e-9)
    assert np.all(np.hypot(*step.T) > 0.5)  # about one sensor pixel per epipolar pixel
