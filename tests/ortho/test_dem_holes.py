"""A DEM with nodata under part of the image (a DSM's holes, the area outside a stereo overlap):
the product still spans the whole image, nodata where the DEM has no height, with a warning
naming the DEM; the pixels where it has heights are those of the complete DEM (to rounding)."""

import numpy as np
import pytest
import rasterio

from jaxgeo.io import read_dem
from jaxgeo.ortho import OrthoSettings, orthorectify
from jaxgeo.tiles import TileSettings
from tests.ortho.conftest import write_dem

# one pixel lattice for both products (the default GSD is taken on the DEM at the image centre)
GRID = dict(settings=OrthoSettings(crs="EPSG:32631", res_m=0.5), tiles=TileSettings(progress=False))


def test_dem_holes_under_the_border_give_nodata_not_an_error(real_data, ventoux_dem_ellipsoidal,
                                                             tmp_path):  # fmt: skip
    image = real_data / "ventoux" / "left_image.tif"
    model = real_data / "phr_ventoux__left_image.geom"
    full = tmp_path / "full.tif"
    orthorectify(image, read_dem(ventoux_dem_ellipsoidal), full, **GRID, model=model)
    with rasterio.open(ventoux_dem_ellipsoidal) as src:
        z, t = src.read(1), src.transform
    with rasterio.open(full) as ds:
        west, east = ds.bounds.left, ds.bounds.right
        ref = ds.read(1)
    # the DEM's cells west of the product's middle meridian (in UTM: roughly) become nodata
    import pyproj

    lon_mid, _ = pyproj.Transformer.from_crs(ds.crs, 4326, always_xy=True).transform(
        0.5 * (west + east), 0.5 * (ds.bounds.bottom + ds.bounds.top)
    )
    lon = t.c + (np.arange(z.shape[1]) + 0.5) * t.a
    holes = np.where(lon[None, :] < lon_mid, np.nan, z)
    dem = write_dem(tmp_path / "holes.tif", holes, t.c, t.f, t.a)
    out = tmp_path / "holes_ortho.tif"
    with pytest.warns(UserWarning, match=r"holes.tif: \d+% of the image border falls where the "
                      "DEM has no height"):  # fmt: skip
        report = orthorectify(image, read_dem(dem), out, **GRID, model=model)
    # (SRTM cells are 90 m, the crop 250 m wide: a cell beside the holes has no bilinear height)
    assert 0.1 < report.valid_fraction < 0.7
    with rasterio.open(out) as ds, rasterio.open(full) as f:
        assert ds.res == f.res and ds.crs == f.crs
        assert abs(ds.bounds.left - f.bounds.left) < 50 and abs(ds.bounds.top - f.bounds.top) < 50
        # the same pixel lattice: compare where both have data
        col0 = round((ds.bounds.left - f.bounds.left) / ds.res[0])
        row0 = round((f.bounds.top - ds.bounds.top) / ds.res[1])
        got = ds.read(1)
    both = np.zeros_like(ref, dtype=bool)
    r = slice(max(row0, 0), min(row0 + got.shape[0], ref.shape[0]))
    c = slice(max(col0, 0), min(col0 + got.shape[1], ref.shape[1]))
    sub = got[r.start - row0 : r.stop - row0, c.start - col0 : c.stop - col0]
    both[r, c] = sub > 0
    assert both.sum() > 0.1 * ref.size
    diff = np.abs(ref[both].astype(float) - sub[both[r, c]])
    # the coarse grid's nodes sit elsewhere (the product's corner moved by a pixel): positions
    # differ by ~1e-5 px, and a few integer values round the other way
    assert diff.max() <= 1 and (diff > 0).mean() < 0.005
