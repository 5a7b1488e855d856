"""A steep synthetic ridge: the terrain it hides from the sensor is masked, on the far side."""

import os

import numpy as np
import pytest
import rasterio

import jaxgeo
from jaxgeo.io import read_dem
from jaxgeo.ortho import orthorectify
from tests.conftest import PLEIADES_TIF
from tests.ortho.conftest import write_dem


@pytest.mark.skipif(
    not os.environ.get("JAXGEO_SLOW"),
    reason="~10 min on 2 cores (per-pixel occlusion march at 1 m DEM cells); JAXGEO_SLOW=1 runs it",
)
def test_ridge_hides_terrain_behind_it(tmp_path, real_data):
    rpc = jaxgeo.read_rpc(real_data / PLEIADES_TIF)
    with rasterio.open(real_data / PLEIADES_TIF) as src:
        width, height = src.width, src.height
    # the image centre's line of sight: where it runs toward the sensor as h grows
    c = np.array([(width - 1) / 2, (height - 1) / 2])
    g0, g1 = np.asarray(rpc.localize(c, 0.0)), np.asarray(rpc.localize(c, 100.0))
    step = 1e-5  # ~1 m cells
    n = 400
    west, north = g0[0] - n / 2 * step, g0[1] + n / 2 * step
    lon = west + (np.arange(n) + 0.5) * step
    lat = north - (np.arange(n) + 0.5) * step
    lon_g, lat_g = np.meshgrid(lon, lat)
    # a 60 m high, 4 m wide wall through the centre, across the look direction
    look = (g1[:2] - g0[:2]) / np.linalg.norm(g1[:2] - g0[:2])  # toward the sensor
    s = (lon_g - g0[0]) * look[0] + (lat_g - g0[1]) * look[1]
    z = np.where(np.abs(s) < 2 * step, 60.0, 0.0)
    dem_path = write_dem(tmp_path / "ridge.tif", z, west, north, step)
    out = tmp_path / "ortho.tif"
    rep = orthorectify(real_data / PLEIADES_TIF, rpc, read_dem(dem_path), out,
                       occlusion="band", progress=False)  # fmt: skip
    assert rep.occluded_fraction > 0.01
    with rasterio.open(out) as ds:
        mask = ds.read(ds.count)
        rows, cols = np.nonzero(mask == 1)
        xs, ys = rasterio.transform.xy(ds.transform, rows, cols)
        import pyproj

        lon_o, lat_o = pyproj.Transformer.from_crs(ds.crs, 4326, always_xy=True).transform(xs, ys)
    s_occ = (np.asarray(lon_o) - g0[0]) * look[0] + (np.asarray(lat_o) - g0[1]) * look[1]
    # hidden terrain lies behind the wall as seen from the sensor (negative side)
    assert np.mean(s_occ < 0) > 0.95
