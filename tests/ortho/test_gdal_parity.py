"""Geometry parity with GDAL: where every ortho pixel samples the image, jaxgeo vs GDAL warp.

A two-band float image holds each pixel's column and row; both jaxgeo and GDAL
(``rasterio.warp.reproject`` with ``rpcs=`` and ``RPC_DEM=``) orthorectify it on the same grid
with bilinear resampling, so each output pixel holds the image position it sampled. GDAL pixel =
jaxgeo + 0.5 cancels in the values (bilinear of a linear ramp returns the sampled position in the
ramp's own convention).
"""

import dataclasses

import numpy as np
import pytest
import rasterio
from rasterio.warp import Resampling, reproject

import jaxgeo
from jaxgeo.io import read_dem, to_rasterio_rpc
from jaxgeo.ortho import orthorectify
from jaxgeo.tiles import TileSettings
from tests.conftest import PLEIADES_TIF
from tests.ortho.conftest import VENTOUX_ORIGIN, write_index_image


def _gdal(index_path, rpcs, dem_path, ref, use_dem=True):
    with rasterio.open(index_path) as src:
        data = src.read()
    out = np.full((2, ref.height, ref.width), np.nan)
    reproject(data, out, rpcs=rpcs, src_crs="EPSG:4326", src_nodata=None,
              dst_transform=ref.transform, dst_crs=ref.crs, dst_nodata=np.nan,
              resampling=Resampling.bilinear, tolerance=0,
              **({"RPC_DEM": str(dem_path)} if use_dem else {}))  # fmt: skip
    return out


def _parity(tmp_path, model, image_origin, rpcs_for_gdal, dem_path, width, height):
    index = write_index_image(tmp_path / "index.tif", width, height)
    out = tmp_path / "ortho.tif"
    rep = orthorectify(index, read_dem(dem_path, height="ellipsoidal"), out,
                       tiles=TileSettings(progress=False), model=model,
                       image_origin=image_origin)  # fmt: skip
    with rasterio.open(out) as ref:
        ours = ref.read()
        assert ref.crs is not None and ref.crs.to_epsg() == int(rep.crs.split(":")[1])
        gdal = _gdal(index, rpcs_for_gdal, dem_path, ref)
    # compare away from the image edge (GDAL and jaxgeo hold edges differently)
    inner = np.all(np.isfinite(ours) & np.isfinite(gdal), axis=0)
    inner &= (ours[0] > 1) & (ours[0] < width - 2) & (ours[1] > 1) & (ours[1] < height - 2)
    assert inner.mean() > 0.5
    diff = np.abs(ours - gdal)[:, inner]
    # the DEM matters: GDAL without it (h = 0) samples elsewhere by many pixels
    flat = _gdal(index, rpcs_for_gdal, dem_path, ref, use_dem=False)
    ok = inner & np.all(np.isfinite(flat), axis=0)
    assert np.nanmean(np.abs(ours - flat)[:, ok]) > 1.0
    return float(diff.mean()), float(diff.max()), rep


def test_ventoux_parity_with_gdal(tmp_path, real_data, ventoux_dem_ellipsoidal):
    rpc = jaxgeo.read_rpc(real_data / "phr_ventoux__left_image.geom")
    # GDAL gets the RPC of the crop itself (offsets moved by the crop origin)
    rpcs = to_rasterio_rpc(rpc)
    rpcs.samp_off -= VENTOUX_ORIGIN[0]
    rpcs.line_off -= VENTOUX_ORIGIN[1]
    mean, worst, rep = _parity(tmp_path, rpc, VENTOUX_ORIGIN, rpcs, ventoux_dem_ellipsoidal,
                               500, 500)  # fmt: skip
    print(f"ventoux: mean |diff| {mean:.2e} px, max {worst:.2e} px, grid error "
          f"{rep.grid_error_px:.2g} px")  # fmt: skip
    assert mean < 0.05
    assert rep.grid_error_px < 0.01


def test_pleiades_parity_with_gdal(tmp_path, real_data, nice_dem_synthetic):
    with rasterio.open(real_data / PLEIADES_TIF) as src:
        rpcs, width, height = src.rpcs, src.width, src.height
    rpc = jaxgeo.read_rpc(real_data / PLEIADES_TIF)
    mean, worst, rep = _parity(tmp_path, rpc, (0.0, 0.0), rpcs, nice_dem_synthetic,
                               width, height)  # fmt: skip
    print(f"pleiades: mean |diff| {mean:.2e} px, max {worst:.2e} px")
    assert mean < 0.05


def test_refuses_to_overwrite(tmp_path, real_data, nice_dem_synthetic):
    out = tmp_path / "exists.tif"
    out.write_bytes(b"keep")
    rpc = jaxgeo.read_rpc(real_data / PLEIADES_TIF)
    with pytest.raises(FileExistsError):
        orthorectify(real_data / PLEIADES_TIF, nice_dem_synthetic, out,
                     tiles=TileSettings(progress=False), model=rpc)  # fmt: skip
    assert out.read_bytes() == b"keep"
    assert dataclasses.is_dataclass(jaxgeo.ortho.OrthoReport)
