"""The exact paths of a tile: blocks refined in full (every block, with ``tol_px=0``) and the
occlusion band give the product of the fast path (to one grey level: float32 against float64
positions); a tile outside the image is no data, not an error."""

import numpy as np
import pytest
import rasterio

from jaxgeo.io import read_dem
from jaxgeo.ortho import OrthoSettings, orthorectify, plan_ortho
from jaxgeo.tiles import Tile, TileSettings
from jaxgeo.tiles.internal import NoData
from tests.ortho.conftest import ventoux_dem_ellipsoidal  # noqa: F401

IN_PROCESS = TileSettings(workers=0, progress=False)


@pytest.fixture(scope="module")
def crop(real_data, ventoux_dem_ellipsoidal):  # noqa: F811
    image = real_data / "ventoux" / "left_image.tif"
    model = real_data / "phr_ventoux__left_image.geom"
    return image, model, read_dem(ventoux_dem_ellipsoidal, height="ellipsoidal")


@pytest.fixture(scope="module")
def fast(crop, tmp_path_factory):
    image, model, dem = crop
    out = tmp_path_factory.mktemp("fast") / "ortho.tif"
    report = orthorectify(image, dem, out, tiles=IN_PROCESS, model=model)
    assert report.refined_fraction == 0.0 and report.grid_error_px < 0.01
    with rasterio.open(out) as ds:
        return ds.read(), report


def test_blocks_refined_in_full_give_the_same_product(crop, fast, tmp_path):
    image, model, dem = crop
    out = tmp_path / "refined.tif"
    report = orthorectify(image, dem, out, OrthoSettings(tol_px=0.0), IN_PROCESS, model=model)
    assert report.refined_fraction > 0.9  # (blocks without data are not checked)
    with rasterio.open(out) as ds:
        refined = ds.read()
    assert np.array_equal(refined > 0, fast[0] > 0)
    diff = np.abs(refined.astype(int) - fast[0].astype(int))
    assert diff.max() <= 1 and diff.mean() < 0.01


def test_occlusion_band_on_the_fast_product(crop, fast, tmp_path):
    image, model, dem = crop
    out = tmp_path / "occ.tif"
    report = orthorectify(image, dem, out, OrthoSettings(occlusion="band"), IN_PROCESS,
                          model=model)  # fmt: skip
    with rasterio.open(out) as ds:
        data = ds.read()
    assert data.shape[0] == fast[0].shape[0] + 1 and report.occluded_fraction is not None
    valid = fast[0][0] > 0
    assert set(np.unique(data[-1][valid])) <= {0, 1} and np.all(data[-1][~valid] == 0)
    seen = valid & (data[-1] == 0)
    assert np.abs(data[0][seen].astype(int) - fast[0][0][seen].astype(int)).max() <= 1


def test_a_tile_off_the_image_has_no_data(crop, tmp_path):
    image, model, dem = crop
    setup = plan_ortho(image, dem, tmp_path / "o.tif", OrthoSettings(tile_px=256), model=model)
    far = Tile("far", 100_000, 100_000, 64, 64)  # 50 km away on the output grid
    with pytest.raises(NoData):
        setup.job(far, tmp_path / "far.tif")
    assert not (tmp_path / "far.tif").exists()
