"""Every raster jaxgeo opens or writes goes through here (one place for GDAL's options and, later,
its virtual file systems): a raster opened for reading, and a GeoTIFF/COG writer."""

from __future__ import annotations

import os
import warnings


def open_raster(path: str | os.PathLike):
    """The rasterio dataset of ``path``, opened for reading. A raster in its own pixel frame (a
    satellite image: no geotransform) is expected, so rasterio's ``NotGeoreferencedWarning`` is
    not raised. Raises rasterio's ``RasterioIOError`` for a file it cannot open."""
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        return rasterio.open(path)


def raster_writer(path: str | os.PathLike, profile: dict):
    """A rasterio dataset opened for writing at ``path`` with ``profile`` (driver, size, bands,
    dtype, CRS, transform, creation options); a context manager. ``path`` is the temporary file
    of an atomic output (:func:`jaxgeo.io.internal.atomic_output`), never the product itself."""
    import rasterio

    return rasterio.open(path, "w", **profile)
