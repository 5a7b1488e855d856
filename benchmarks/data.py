"""Where the benchmarks' input data lives, and the small rasters the ortho study writes.

The real scenes are read in place from ``../shared/data/real`` (beside the repository; the
AGPL s2p triplet cannot be vendored), as the test suite's ``shared_data`` fixture does.
"""

from __future__ import annotations

import pathlib

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
REAL_DATA = REPO.parent / "shared" / "data" / "real"
PLEIADES_TIF = REAL_DATA / "PHR1B_P_201709281038393_SEN_PRG_FC_178609-001.tif"
VENTOUX_LEFT_GEOM = REAL_DATA / "phr_ventoux__left_image.geom"
S2P_TRIPLET = REAL_DATA / "s2p_triplet"

VENTOUX_ORIGIN = (5000.0, 5000.0)
"""Model pixel of the Ventoux ``left_image.tif``'s first pixel (as in tests/ortho)."""


def write_index_image(path, width: int, height: int):
    """A 2-band float64 GeoTIFF holding each pixel's own column and row (jaxgeo convention)."""
    import rasterio

    col, row = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    with rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=2,
                       dtype="float64") as dst:  # fmt: skip
        dst.write(np.stack([col, row]))
    return path


def write_dem(path, z: np.ndarray, west: float, north: float, step: float):
    """``z`` as a one-band float64 GeoTIFF in EPSG:4326 (NaN no-data), ``step`` degrees a cell."""
    import rasterio
    from affine import Affine

    profile = dict(driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float64",
                   crs="EPSG:4326", transform=Affine(step, 0, west, 0, -step, north),
                   nodata=np.nan)  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(z, 1)
    return path
