"""The per-tile kernels: positions of every pixel equal to the exact float64 mapping (float32
relative positions within 2e-3 px, float64 within 1e-6 px), resampling equal to independent
references (scipy's map_coordinates, a numpy Keys cubic), edge and nodata rules."""

import numpy as np
import pyproj
import pytest
from scipy.ndimage import map_coordinates

import jaxgeo
from jaxgeo.io import read_dem
from jaxgeo.ortho._kernel import map_pixels, sample_window
from jaxgeo.ortho._mapping import map_tile
from tests.ortho.conftest import VENTOUX_ORIGIN, ventoux_dem_ellipsoidal  # noqa: F401

STEP, TILE = 16, 128


@pytest.fixture(scope="module")
def tile(real_data, ventoux_dem_ellipsoidal):  # noqa: F811
    """The Ventoux crop's model (its frame), a DEM window and the nodes of a 128 px UTM tile
    at 0.5 m on the crop's centre."""
    from jaxgeo.models import Biased, ShiftBias

    rpc = jaxgeo.read_rpc(real_data / "phr_ventoux__left_image.geom")
    model = Biased(rpc, ShiftBias(np.array(VENTOUX_ORIGIN)))
    lon, lat = (float(v) for v in rpc.localize(np.array([5250.0, 5250.0]), 1000.0)[:2])
    dem = read_dem(ventoux_dem_ellipsoidal, height="ellipsoidal")
    grid = dem.grid((lon - 0.01, lat - 0.01, lon + 0.01, lat + 0.01))
    to_utm = pyproj.Transformer.from_crs(4326, 32631, always_xy=True)
    to_ll = pyproj.Transformer.from_crs(32631, 4326, always_xy=True)
    e0, n0 = to_utm.transform(lon, lat)
    k = np.arange(0, TILE + 1, STEP)
    xx, yy = np.meshgrid(e0 + (k + 0.5) * 0.5, n0 - (k + 0.5) * 0.5)
    nodes = np.stack(to_ll.transform(xx, yy), axis=-1)
    return model, grid, nodes


@pytest.mark.parametrize("dtype,tol", [("float32", 2e-3), ("float64", 1e-6)])
def test_positions_equal_the_exact_mapping(tile, dtype, tol):
    model, grid, nodes = tile
    xy, ref, lo, hi, err = map_pixels(model, grid, nodes, STEP, dtype)
    assert str(np.asarray(xy).dtype) == dtype
    exact, _, _, err_exact = map_tile(model, grid, nodes, STEP, TILE, TILE)
    xy = np.moveaxis(np.asarray(xy, dtype=float), 0, -1) + np.asarray(ref)
    exact = np.asarray(exact)
    assert np.all(np.isfinite(xy))
    assert np.abs(xy - exact).max() < tol
    # the bounds and the check error: what the tile reads and refines by
    rel = xy - np.asarray(ref)
    assert np.all(np.asarray(lo) <= rel.reshape(-1, 2).min(0) + tol)  # bounds of the window
    assert np.all(np.asarray(hi) >= rel.reshape(-1, 2).max(0) - tol)
    assert (
        np.asarray(err).max() < 0.01 and np.abs(np.asarray(err) - np.asarray(err_exact)).max() < tol
    )


def _keys_reference(window, x, y):
    """Keys cubic convolution (a = -0.5) at (x, y), edge pixels held (numpy, loops)."""

    def w(d):
        d = abs(d)
        if d <= 1:
            return 1.5 * d**3 - 2.5 * d**2 + 1
        return -0.5 * d**3 + 2.5 * d**2 - 4 * d + 2 if d < 2 else 0.0

    rows, cols = window.shape
    out = np.empty(len(x))
    for k, (xi, yi) in enumerate(zip(x, y, strict=True)):
        c0, r0 = int(np.floor(xi)), int(np.floor(yi))
        out[k] = sum(w(yi - (r0 + i)) * w(xi - (c0 + j))
                     * window[min(max(r0 + i, 0), rows - 1), min(max(c0 + j, 0), cols - 1)]
                     for i in range(-1, 3) for j in range(-1, 3))  # fmt: skip
    return out


@pytest.mark.parametrize("method", ["nearest", "bilinear", "cubic"])
def test_resampling_equals_independent_references(method):
    rng = np.random.default_rng(1)
    window = rng.uniform(0, 1000, (1, 40, 50))
    n = 2000
    x, y = rng.uniform(0, 49, n), rng.uniform(0, 39, n)
    offset = np.array([7.0, 3.0])  # positions given in a frame where the window starts at 7, 3
    xy = np.stack([x + offset[0], y + offset[1]]).reshape(2, 1, n)
    big = np.array([-1e9, -1e9, 1e9, 1e9])
    values, valid, missed = sample_window(window, xy, offset, np.array([50, 40]), big, np.nan,
                                          method, "float64")  # fmt: skip
    values, valid = np.asarray(values)[0, 0], np.asarray(valid)[0]
    assert valid.all() and int(missed) == 0
    if method == "cubic":
        expected = _keys_reference(window[0], x, y)
    else:
        expected = map_coordinates(window[0], [y, x], order=0 if method == "nearest" else 1,
                                   mode="nearest")  # fmt: skip
    assert np.abs(values - expected).max() < 1e-9


def test_edges_nodata_padding_and_integer_output():
    window = np.zeros((1, 8, 16), dtype=np.uint16)  # padded: only 10 x 6 px are real
    window[0, :6, :10] = np.arange(60, dtype=np.uint16).reshape(6, 10) * 1000
    # image pixel area in window coordinates: the window is the image's top-left corner
    image_box = np.array([-0.5, -0.5, 9.5, 5.5])
    x = np.array([-0.5, -0.6, 9.5, 9.6, 4.5, 3.0, 12.0, np.nan])
    y = np.array([0.0, 0.0, 5.5, 5.0, 2.25, 1.0, 1.0, 1.0])
    xy = np.stack([x, y]).reshape(2, 1, -1).astype(np.float32)
    v, valid, missed = sample_window(window, xy, np.zeros(2), np.array([10, 6]), image_box, 0,
                                     "bilinear", "uint16")  # fmt: skip
    v, valid = np.asarray(v)[0, 0], np.asarray(valid)[0]
    # the outer half pixel holds the edge; beyond it, or NaN: nodata
    assert list(valid) == [True, False, True, False, True, True, False, False]
    assert v[0] == 0 and v[2] == 59000 and v[5] == 13000
    assert v[4] == 27000  # bilinear: 24500 on row 2, 34500 on row 3, a quarter of the way
    assert int(missed) == 0
    # a window read too small: positions inside the image but outside the window are counted
    wide = np.array([-0.5, -0.5, 99.5, 99.5])
    _, _, missed = sample_window(window, xy, np.zeros(2), np.array([10, 6]), wide, 0, "nearest",
                                 "uint16")  # fmt: skip
    assert int(missed) == 2  # x = 9.6 and x = 12
    # clipped to the output type
    hot = np.full((1, 4, 4), 7e4)
    v, _, _ = sample_window(hot, np.full((2, 1, 1), 1.5), np.zeros(2), np.array([4, 4]),
                            np.array([-0.5, -0.5, 3.5, 3.5]), 0, "cubic", "uint16")  # fmt: skip
    assert int(np.asarray(v)[0, 0, 0]) == 65535
