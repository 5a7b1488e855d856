"""``localize_on_dem``: exact on flat DEMs, agrees with GDAL's RPC_DEM transformer on SRTM,
first intersection behind ridges, NaN + status outside, gradients; ``read_dem`` geoids."""

import jax
import numpy as np
import pytest
from jax.test_util import check_grads

import jaxgeo
from jaxgeo.io import read_dem, to_rasterio_rpc
from jaxgeo.models import DEMGrid, DEMStatus, localize_on_dem
from tests.ortho.conftest import ventoux_dem_ellipsoidal  # noqa: F401  (fixture)
from tests.typecheck import unchecked

GTX = "ventoux/dem/egm96_15_crop_lon3-8_lat42-47.gtx"
SRTM = "ventoux/dem/N44E005_srtm90.tif"


@pytest.fixture(scope="module")
def left(real_data):
    return jaxgeo.read_rpc(real_data / "phr_ventoux__left_image.geom")


N_GRID = 100  # every synthetic DEM of this file has this shape and every batch N_POINTS
N_POINTS = 64  # points: localize_on_dem compiles once per (grid shape, batch), not per test


def _hills(rpc, n=N_GRID, step=0.003):
    lon0, lat0 = (float(v) for v in rpc.ground_offset[:2])
    lon = lon0 - 0.15 + step * np.arange(n)
    lat = lat0 + 0.15 - step * np.arange(n)
    lon_g, lat_g = np.meshgrid(lon, lat)
    z = 800 + 300 * np.sin(lon_g * 60) * np.cos(lat_g * 50)
    return DEMGrid(z, (lon[0], lat[0]), (step, -step))


_localize_jit = jax.jit(localize_on_dem)


def localize_jit(model, xy, grid):
    """``localize_on_dem`` on ``xy`` padded to ``N_POINTS`` rows (one compilation)."""
    xy = jax.numpy.asarray(xy, dtype=float)
    n = xy.shape[0]
    pad = jax.numpy.concatenate([xy, jax.numpy.repeat(xy[:1], max(N_POINTS - n, 0), axis=0)])
    g, st = _localize_jit(model, pad, grid)
    return g[:n], st[:n]


def test_flat_dem_equals_localize(left):
    z = np.full((N_GRID, N_GRID), 612.5)
    lon0, lat0 = (float(v) for v in left.ground_offset[:2])
    grid = DEMGrid(z, (lon0 - 0.2, lat0 + 0.2), (0.004, -0.004))
    xy = np.array([[5000.0, 5000.0], [5400.0, 5300.0], [12000.0, 9000.0]])
    g, st = localize_jit(left, xy, grid)
    assert np.all(np.asarray(st) == DEMStatus.OK)
    np.testing.assert_allclose(g, left.localize(xy, 612.5), atol=1e-9)


def test_hills_reproject_and_lie_on_dem(left):
    grid = _hills(left)
    rng = np.random.default_rng(1)
    xy = np.stack([rng.uniform(4000, 8000, 32), rng.uniform(4000, 8000, 32)], -1)
    g, st = localize_jit(left, xy, grid)
    assert np.all(np.asarray(st) == DEMStatus.OK)
    np.testing.assert_allclose(left.project(g), xy, atol=1e-6)
    np.testing.assert_allclose(g[:, 2], grid.height(g[:, :2]), atol=1e-6)


def test_outside_and_bad_input_are_nan_with_status(left):
    grid = _hills(left, step=0.0004)  # a small DEM: most of the scene is outside it
    xy = np.array([[np.nan, 1.0], [30000.0, 30000.0]])
    g, st = localize_jit(left, xy, grid)
    assert np.all(np.isnan(g))
    assert list(np.asarray(st)) == [DEMStatus.BAD_INPUT, DEMStatus.OUTSIDE]
    z = np.asarray(_hills(left).heights_m).copy()
    z[:, :] = np.nan
    g, st = localize_jit(left, np.array([[5000.0, 5000.0]]), DEMGrid(z, (0.0, 50.0), (1.0, -1.0)))
    assert np.isnan(g).all() and int(st[0]) != DEMStatus.OK


def test_first_intersection_in_front_of_a_wall(left):
    """A wall between the sensor and the terrain: the ray stops on the wall, not behind it."""
    grid = _hills(left)
    xy = np.array([[5250.0, 5250.0]])
    g_open, _ = localize_jit(left, xy, grid)
    # the line of sight climbs toward the sensor: put a 3000 m wall across it, half-way up
    g_high = left.localize(xy, 1500.0)
    z = np.asarray(grid.heights_m).copy()
    col, row = np.asarray(grid.pixel(g_high[:, :2]))[0]
    z[int(row) - 3 : int(row) + 4, int(col) - 3 : int(col) + 4] = 3000.0
    g_wall, st = localize_jit(left, xy, DEMGrid(z, grid.origin, grid.step))
    assert int(st[0]) == DEMStatus.OK
    assert float(g_wall[0, 2]) > 1400.0 > float(g_open[0, 2])
    np.testing.assert_allclose(left.project(g_wall), xy, atol=1e-6)


def test_gradients(left):
    grid = _hills(left)
    xy = np.array([[5100.0, 5200.0], [5300.0, 5050.0]])
    # forward mode in the image point, reverse mode in the DEM heights: both paths through the
    # implicit step, one compilation each
    check_grads(lambda p: localize_jit(left, p, grid)[0], (xy,), order=1, modes=["fwd"],
                atol=1e-6, rtol=1e-4, eps=1e-3)  # fmt: skip
    check_grads(
        lambda z: localize_jit(left, xy, DEMGrid(z, grid.origin, grid.step))[0][:, 2],
        (grid.heights_m,),
        order=1,
        modes=["rev"],
        atol=1e-6,
        rtol=1e-4,
        eps=1e-3,
    )


def test_agrees_with_gdal_rpc_dem(left, real_data, ventoux_dem_ellipsoidal):  # noqa: F811
    from rasterio.transform import RPCTransformer

    dem = read_dem(ventoux_dem_ellipsoidal, height="ellipsoidal")
    grid = dem.grid((5.16, 44.16, 5.2395, 44.2395))  # N_GRID x N_GRID cells: no new compile
    assert grid.heights_m.shape == (N_GRID, N_GRID)
    rng = np.random.default_rng(0)
    xy = np.stack([rng.uniform(5000, 5500, 64), rng.uniform(5000, 5500, 64)], -1)
    g, st = localize_jit(left, xy, grid)
    assert np.all(np.asarray(st) == DEMStatus.OK)
    with RPCTransformer(to_rasterio_rpc(left), RPC_DEM=str(ventoux_dem_ellipsoidal)) as tr:
        lon, lat = tr.xy(xy[:, 1] + 0.5, xy[:, 0] + 0.5, offset="ul")  # GDAL = ours + 0.5
    d_e = (np.asarray(g[:, 0]) - np.asarray(lon)) * 111_320 * np.cos(np.radians(44.2))
    d_n = (np.asarray(g[:, 1]) - np.asarray(lat)) * 111_320
    dist = np.hypot(d_e, d_n)
    # GDAL stops its own iteration at ~0.1 px (~5 cm); jaxgeo reprojects to 1e-6 px
    assert dist.mean() < 0.05 and dist.max() < 0.15
    np.testing.assert_allclose(left.project(g), xy, atol=1e-6)


def test_shareloc_geoid_and_dem_values(real_data):
    """shareloc test_dtm_intersection.py: geoid heights and DEM + geoid (reference_values.json)."""
    from jaxgeo.io._geoid import read_geoid

    geoid = read_geoid(real_data / GTX)
    np.testing.assert_allclose(geoid(5.19368066, 44.20749145), 50.8618354, atol=1e-6)
    np.testing.assert_allclose(geoid(5.17381589, 44.22559175), 50.8761, atol=1e-6)
    dem = read_dem(real_data / SRTM, height="orthometric", geoid=real_data / GTX)
    h = dem(np.array([5.002777777777778, 44.99444444444445]))
    np.testing.assert_allclose(h, 221.73, rtol=0.01)
    grid = dem.grid((5.0, 44.9, 5.1, 44.999))
    np.testing.assert_allclose(grid.height(np.array([5.002777777777778, 44.99444444444445])), h)


def test_read_dem_errors(real_data, tmp_path):
    with pytest.raises(ValueError, match="need a geoid"):
        read_dem(real_data / SRTM, height="orthometric")
    with pytest.raises(ValueError, match="unknown geoid"):
        read_dem(real_data / SRTM, geoid="egm1066")
    dem = read_dem(real_data / SRTM)
    with pytest.raises(ValueError, match=r"covers only 33\.5%"):
        dem.grid((5.8, 44.8, 6.2, 45.1))
    import rasterio

    nocrs = tmp_path / "nocrs.tif"
    with rasterio.open(nocrs, "w", driver="GTiff", width=4, height=4, count=1,
                       dtype="float32") as dst:  # fmt: skip
        dst.write(np.zeros((1, 4, 4), dtype="float32"))
    with pytest.raises(ValueError, match="no CRS"):
        read_dem(nocrs)


def test_method_takes_what_read_dem_returns(left, ventoux_dem_ellipsoidal):  # noqa: F811
    """``model.localize_on_dem(xy, read_dem(...))``: the window is read for the caller, for any
    model (here a biased RPC: its base RPC's validity heights), same answer as a grid by hand."""
    dem = read_dem(ventoux_dem_ellipsoidal, height="ellipsoidal")
    biased = jaxgeo.Biased(left, jaxgeo.ShiftBias((1.5, -2.0)))
    assert biased.base_rpc() is left and left.base_rpc() is left
    rng = np.random.default_rng(3)
    xy = np.stack([rng.uniform(5000, 5500, 64), rng.uniform(5000, 5500, 64)], -1)
    g, st = biased.localize_on_dem(xy, dem)
    assert np.all(np.asarray(st) == DEMStatus.OK)
    by_hand, _ = localize_jit(biased, xy, dem.grid((5.16, 44.16, 5.2395, 44.2395)))
    np.testing.assert_allclose(g, by_hand, atol=1e-9)
    np.testing.assert_allclose(biased.project(g), xy, atol=1e-6)
    with pytest.raises(TypeError, match="DEMGrid or a DEM"):  # the library's own message
        unchecked(localize_on_dem)(left, xy, str(ventoux_dem_ellipsoidal))


def test_shareloc_rpc_direct_dtm(real_data):
    """shareloc's ``test_rpc_direct_dtm`` (tests/geomodels/test_rpc.py, commit df45fae6): the
    point of its NAD83 30" MNT at index (row 10.5, col 20.5) (index ``i`` the centre of cell
    ``i``; bilinear between centres: the height 58 m), projected with the Pleiades RPC and
    localised back on the MNT within 1e-7 deg and 1e-4 m, shareloc's tolerances. Before issue
    53: 1.2e-6 deg, 0.5 m: the NAD83 grid was resampled onto a WGS84 one of other cells (a
    second bilinear interpolation); PROJ takes NAD83 as WGS84 there, so its grid is kept."""
    import rasterio

    path = real_data / "shareloc_dtm" / "MNT_P1BP--2017092838284574CP.tif"
    rpc = jaxgeo.read_rpc(real_data / "RPC_PHR1B_P_201709281038393_SEN_PRG_FC_178609-001.XML")
    with rasterio.open(path) as f:
        z, t = f.read(1).astype(float), f.transform
    row, col = 10.5, 20.5
    lon, lat = t * (col + 0.5, row + 0.5)  # shareloc's index_to_ter
    r0, c0 = int(row), int(col)
    alt = float(np.mean(z[r0 : r0 + 2, c0 : c0 + 2]))  # its interpolate at the cells' middle
    assert alt == 58.0
    dem = read_dem(path)
    xy = np.asarray(rpc.project(np.array([lon, lat, alt])))
    g, status = rpc.localize_on_dem(xy[None], dem)
    g = np.asarray(g)[0]
    assert int(np.asarray(status)[0]) == DEMStatus.OK
    assert abs(g[0] - lon) < 1e-7 and abs(g[1] - lat) < 1e-7, g - [lon, lat, alt]
    assert abs(g[2] - alt) < 1e-4, g
    # the grid the search uses is the file's own cells (no resampling)
    grid = dem.grid((lon - 0.01, lat - 0.01, lon + 0.01, lat + 0.01))
    np.testing.assert_allclose(np.asarray(grid.step), [t.a, t.e], rtol=1e-12)
