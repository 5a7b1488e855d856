"""A steep synthetic ridge: the terrain it hides from the sensor is masked, on the far side."""

import numpy as np
import pyproj
import pytest
import rasterio

import jaxgeo
from jaxgeo.io import SensorImage, read_dem
from jaxgeo.models import DEMGrid, DEMStatus, localize_on_dem
from jaxgeo.ortho import OrthoSettings, orthorectify
from jaxgeo.ortho._occlusion import occluded_pixels
from jaxgeo.tiles import TileSettings
from tests.conftest import PLEIADES_TIF
from tests.ortho.conftest import write_dem

STEP = 1e-5  # ~1 m cells


@pytest.fixture(scope="module")
def ridge(tmp_path_factory, real_data):
    """The Pleiades crop's RPC, the image centre's ground point ``g0``, the horizontal look
    direction toward the sensor, and a DEM with a 60 m high, 4 m wide wall through ``g0``
    across the look direction."""
    rpc = jaxgeo.read_rpc(real_data / PLEIADES_TIF)
    with rasterio.open(real_data / PLEIADES_TIF) as src:
        width, height = src.width, src.height
    c = np.array([(width - 1) / 2, (height - 1) / 2])
    g0, g1 = np.asarray(rpc.localize(c, 0.0)), np.asarray(rpc.localize(c, 100.0))
    n = 400
    west, north = g0[0] - n / 2 * STEP, g0[1] + n / 2 * STEP
    lon = west + (np.arange(n) + 0.5) * STEP
    lat = north - (np.arange(n) + 0.5) * STEP
    lon_g, lat_g = np.meshgrid(lon, lat)
    look = (g1[:2] - g0[:2]) / np.linalg.norm(g1[:2] - g0[:2])  # toward the sensor
    s = (lon_g - g0[0]) * look[0] + (lat_g - g0[1]) * look[1]
    z = np.where(np.abs(s) < 2 * STEP, 60.0, 0.0)
    path = write_dem(tmp_path_factory.mktemp("ridge") / "ridge.tif", z, west, north, STEP)
    grid = DEMGrid(z, (west + STEP / 2, north - STEP / 2), (STEP, -STEP))
    return rpc, g0, look, read_dem(path), grid


def test_ridge_hides_terrain_behind_it(ridge, tmp_path, real_data):
    rpc, g0, look, dem, _ = ridge
    out = tmp_path / "ortho.tif"
    # the crop's file carries a flipped pixel-space geotransform open_image refuses: the image
    # is given with its RPC in its own pixel frame
    image = SensorImage("crop", rpc, (0.0, 0.0), real_data / PLEIADES_TIF, (128, 128), None, rpc)
    rep = orthorectify(image, dem, out, OrthoSettings(occlusion="band"),
                       TileSettings(progress=False))  # fmt: skip
    assert rep.occluded_fraction > 0.01
    with rasterio.open(out) as ds:
        mask = ds.read(ds.count)
        rows, cols = np.nonzero(mask == 1)
        xs, ys = rasterio.transform.xy(ds.transform, rows, cols)
        lon_o, lat_o = pyproj.Transformer.from_crs(ds.crs, 4326, always_xy=True).transform(xs, ys)
    s_occ = (np.asarray(lon_o) - g0[0]) * look[0] + (np.asarray(lat_o) - g0[1]) * look[1]
    # hidden terrain lies behind the wall as seen from the sensor (negative side)
    assert np.mean(s_occ < 0) > 0.95


def test_ground_march_agrees_with_exact_first_intersection(ridge):
    """The straight-line march in ground space flags the same points as the exact first
    intersection of the line of sight (:func:`localize_on_dem`) along a profile across the
    wall, except within half a DEM cell of the shadow's edges."""
    rpc, g0, look, _, grid = ridge
    s = np.linspace(-40.0, 40.0, 64) * STEP  # 80 m profile across the wall
    lonlat = g0[:2] + s[:, None] * look
    h = np.asarray(grid.height(lonlat))
    xy = np.asarray(rpc.project(np.concatenate([lonlat, h[:, None]], axis=1)))
    fast = occluded_pixels(rpc, grid, xy[None], lonlat[None], h[None], thresh_m=1.0)[0]
    g, st = localize_on_dem(rpc, xy, grid)
    g = np.asarray(g)
    dist_m = np.hypot((g[:, 0] - lonlat[:, 0]) * np.cos(np.radians(g0[1])),
                      g[:, 1] - lonlat[:, 1]) * 111_320.0  # fmt: skip
    exact = (np.asarray(st) == DEMStatus.OK) & (dist_m > 1.0)
    assert exact.sum() >= 5  # the shadow is on the profile
    edge = np.abs(np.diff(exact.astype(int), prepend=exact[0], append=exact[-1]))
    near_edge = (edge[:-1] + edge[1:]) > 0
    assert np.array_equal(fast[~near_edge], exact[~near_edge])
