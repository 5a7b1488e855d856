"""Every raster jaxgeo opens or writes goes through here (one place for GDAL's options and its
virtual file systems): a raster opened for reading (a local file or a URL, see
:mod:`jaxgeo.io._remote`), and a GeoTIFF/COG writer."""

from __future__ import annotations

import os
import warnings

from ._remote import is_remote, remote_env


def open_raster(path: str | os.PathLike, sidecars: bool = False):
    """The rasterio dataset of ``path``, opened for reading. A raster in its own pixel frame (a
    satellite image: no geotransform) is expected, so rasterio's ``NotGeoreferencedWarning`` is
    not raised. Raises rasterio's ``RasterioIOError`` for a file it cannot open.

    ``path`` may be a URL (``https://``, ``s3://``, ``gs://``, a :class:`RemotePath` or a GDAL
    ``/vsi...`` path): GDAL reads it by range requests with :data:`URL_GDAL_OPTIONS`, without
    looking for sidecars unless ``sidecars`` (then one request each)."""
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings(), remote_env(path, sidecars):
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        return rasterio.open(os.fspath(path) if is_remote(path) else path)


def raster_writer(path: str | os.PathLike, profile: dict):
    """A rasterio dataset opened for writing at ``path`` with ``profile`` (driver, size, bands,
    dtype, CRS, transform, creation options); a context manager. ``path`` is the temporary file
    of an atomic output (:func:`jaxgeo.io.internal.atomic_output`), never the product itself."""
    import rasterio

    return rasterio.open(path, "w", **profile)
