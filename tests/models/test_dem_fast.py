"""``localize_on_dem``'s fast search agrees with the robust one (each point localised at every
march step) on steep terrain: cliffs, a tower, a nodata hole, points off the DEM, bad input --
the same statuses, the same ground points (1e-9 deg, 1e-6 m); numpy in, numpy out."""

import numpy as np
import pytest

import jaxgeo
from jaxgeo.models import DEMGrid, DEMStatus, _dem_fast, localize_on_dem

N_GRID = 100
OPTIONS = (4096, 100, 1e-6)  # localize_on_dem's defaults, as the robust search is called here


@pytest.fixture(scope="module")
def left(real_data):
    return jaxgeo.read_rpc(real_data / "phr_ventoux__left_image.geom")


def _steep(rpc, step=0.0015):
    """Hills with a 1500 m cliff (one cell wide), a 2000 m tower of 3 x 3 cells and a nodata
    hole, over the middle of the scene (about 0.15 deg: part of the scene is off it)."""
    lon0, lat0 = (float(v) for v in rpc.ground_offset[:2])
    lon = lon0 - 0.075 + step * np.arange(N_GRID)
    lat = lat0 + 0.075 - step * np.arange(N_GRID)
    lon_g, lat_g = np.meshgrid(lon, lat)
    z = 800 + 300 * np.sin(lon_g * 60) * np.cos(lat_g * 50)
    z[:, 40:] += 1500.0  # a cliff facing west
    z[60:63, 20:23] = 2800.0  # a tower
    z[10:30, 60:85] = np.nan  # a hole
    return DEMGrid(z, (lon[0], lat[0]), (step, -step))


def _points(rpc, grid, n=600, seed=5):
    """Image points over the DEM and around it (some off it), one NaN point."""
    rng = np.random.default_rng(seed)
    lon0, lat0 = (float(v) for v in grid.origin)
    span = (N_GRID - 1) * float(grid.step[0])
    lonlat = np.stack(
        [lon0 - 0.15 * span + 1.3 * span * rng.random(n),
         lat0 + 0.15 * span - 1.3 * span * rng.random(n)], -1
    )  # fmt: skip
    h = np.asarray(grid.height(np.clip(lonlat, [lon0, lat0 - span], [lon0 + span, lat0])))
    xy = np.asarray(rpc.project(np.concatenate([lonlat, np.nan_to_num(h, nan=800.0)[:, None]], -1)))
    xy[0] = np.nan
    return xy


def test_fast_search_agrees_with_robust_on_steep_terrain(left):
    grid = _steep(left)
    xy = _points(left, grid)
    g, st = localize_on_dem(left, xy, grid)
    assert isinstance(g, np.ndarray) and isinstance(st, np.ndarray)  # numpy in, numpy out
    assert g.shape == (len(xy), 3) and st.shape == (len(xy),)
    g_ref, st_ref = (np.asarray(v) for v in _dem_fast._robust_chunk(left, grid, OPTIONS, xy))
    np.testing.assert_array_equal(st, st_ref)
    counts = np.bincount(st, minlength=len(DEMStatus))
    # every outcome is exercised: ok, off the DEM, nodata, bad input
    assert counts[DEMStatus.OK] > 200 and counts[DEMStatus.OUTSIDE] > 20
    assert counts[DEMStatus.NODATA] > 0 and counts[DEMStatus.BAD_INPUT] == 1
    ok = st == DEMStatus.OK
    assert np.all(np.isnan(g[~ok])) and np.all(np.isfinite(g[ok]))
    np.testing.assert_allclose(g[ok, :2], g_ref[ok, :2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(g[ok, 2], g_ref[ok, 2], rtol=0, atol=1e-6)
    np.testing.assert_allclose(left.project(g[ok]), xy[ok], atol=1e-6)
    # the fast search decided most points itself (the robust search is not what was tested)
    _, _, robust = _dem_fast._fast_chunk(left, grid, OPTIONS, xy)
    assert np.mean(robust) < 0.1, np.mean(robust)
    # on the cliff, the first intersection: points on the cliff top seen from the sensor
    assert np.any(g[ok, 2] > 2000.0)


def test_points_left_to_the_robust_search_keep_their_results(left, monkeypatch):
    """Every point left to the robust search: its results, statuses and ground points, whole
    (the fast search's own results of those points are not kept)."""
    grid = _steep(left)
    xy = _points(left, grid, n=40, seed=7)
    fast = _dem_fast._fast_chunk

    def leave_all(model, dem, options, points):
        g, st, robust = fast(model, dem, options, points)
        return g, st, np.ones_like(robust)

    monkeypatch.setattr(_dem_fast, "_fast_chunk", leave_all)
    g, st = localize_on_dem(left, xy, grid)
    g_ref, st_ref = (np.asarray(v) for v in _dem_fast._robust_chunk(left, grid, OPTIONS, xy))
    np.testing.assert_array_equal(st, st_ref)
    np.testing.assert_array_equal(g, g_ref)


def test_jax_in_jax_out_and_shapes(left):
    import jax.numpy as jnp

    grid = _steep(left)
    xy = _points(left, grid, n=12, seed=3)[2:].reshape(2, 5, 2)
    g_np, st_np = localize_on_dem(left, xy, grid)
    g, st = localize_on_dem(left, jnp.asarray(xy), grid)
    assert not isinstance(g, np.ndarray) and g.shape == (2, 5, 3) and st.shape == (2, 5)
    np.testing.assert_array_equal(np.asarray(g), g_np)
    np.testing.assert_array_equal(np.asarray(st), st_np)
