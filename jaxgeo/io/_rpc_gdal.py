"""RPCs inside rasters: GeoTIFF RPC tags, and whatever else GDAL reads (NITF RPC00A/B TREs,
JPEG 2000 with DIMAP sidecars, PAM ``.aux.xml``), through rasterio.

GeoTIFF stores the RPC as 92 binary doubles in the ``RPCCoefficientTag`` (50844):
``ERR_BIAS, ERR_RAND, LINE_OFF, SAMP_OFF, LAT_OFF, LONG_OFF, HEIGHT_OFF, LINE_SCALE, SAMP_SCALE,
LAT_SCALE, LONG_SCALE, HEIGHT_SCALE``, then line num/den and sample num/den (20 each, RPC00B).
GDAL hands these to Python as text rounded to 15 significant digits, so the tag is read here
directly (bit-exact) and rasterio's ``src.rpcs`` is the fallback for every other raster. Pixel
offsets are in the RPC standard convention (ours); GDAL's RPC transformer gives ours + 0.5.
"""

from __future__ import annotations

import math
import os
import pathlib
import shutil
import struct
import warnings

import numpy as np
from jaxtyping import ArrayLike

from ..models import RPC
from ._atomic import atomic_output, refuse_existing
from ._raster import open_raster
from ._remote import open_bytes
from ._rpc_accuracy import RPCAccuracy, stated_value
from ._rpc_common import RPCFormatError, assemble_rpc, vendor_values
from ._rpc_keys import COEFFS, GEOTIFF_TAG_ORDER, N_TERMS, STYLES, vendor_items

TIFFTAG_RPCCOEFFICIENT = 50844
_TIFF_DOUBLE = 12
_RASTERIO = STYLES["rasterio"]
_TAG_LENGTH = sum(N_TERMS if name in COEFFS else 1 for name in GEOTIFF_TAG_ORDER)  # 92


def read_tiff_rpc_tag(path: str | os.PathLike, source: str | None = None) -> np.ndarray | None:
    """The 92 doubles of the RPCCoefficientTag in the first IFD of a (Big)TIFF, or None.

    None when the file is no TIFF or has no such tag; RPCFormatError when the tag is there but
    its data lies beyond the end of the file (a truncated file).
    """
    try:
        with open_bytes(path) as f:  # a URL: a range request or two, not the file
            head = f.read(16)
            endian = {b"II": "<", b"MM": ">"}.get(head[:2])
            if endian is None or len(head) < 16:
                return None
            magic = struct.unpack(endian + "H", head[2:4])[0]
            if magic == 42:  # classic TIFF: 2-byte entry count, 12-byte entries
                ifd, count_fmt, entry_fmt = struct.unpack(endian + "I", head[4:8])[0], "H", "HHII"
            elif magic == 43:  # BigTIFF: 8-byte count, 20-byte entries
                ifd, count_fmt, entry_fmt = struct.unpack(endian + "Q", head[8:16])[0], "Q", "HHQQ"
            else:
                return None
            f.seek(ifd)
            count_size, entry_size = struct.calcsize(count_fmt), struct.calcsize(entry_fmt)
            (n_entries,) = struct.unpack(endian + count_fmt, f.read(count_size))
            table = f.read(n_entries * entry_size)
            for k in range(min(n_entries, len(table) // entry_size)):
                tag, typ, count, offset = struct.unpack_from(
                    endian + entry_fmt, table, k * entry_size
                )
                if tag == TIFFTAG_RPCCOEFFICIENT:
                    if typ != _TIFF_DOUBLE or count != _TAG_LENGTH:
                        return None
                    f.seek(offset)
                    raw = f.read(8 * count)
                    if len(raw) != 8 * count:
                        raise RPCFormatError(
                            f"{source or path}: RPCCoefficientTag data at byte {offset} is cut "
                            "off (truncated file?)"
                        )
                    return np.frombuffer(raw, dtype=endian + "f8").astype(np.float64)
    except (OSError, struct.error):
        return None
    return None


def from_rasterio_rpc(rpcs, source: str = "rasterio RPC") -> RPC:
    """A :class:`jaxgeo.models.RPC` from a :class:`rasterio.rpc.RPC` (same pixel convention)."""
    scalars = {ours: getattr(rpcs, theirs) for theirs, ours in _RASTERIO.scalar_names().items()}
    coeffs = {ours: list(getattr(rpcs, theirs)) for theirs, ours in _RASTERIO.coeff_names().items()}
    return assemble_rpc(scalars, coeffs, source)


def to_rasterio_rpc(rpc: RPC):
    """A :class:`rasterio.rpc.RPC` holding ``rpc`` (RPC00B, full precision, err_* unknown)."""
    from rasterio.rpc import RPC as RasterioRPC

    items = vendor_items(_RASTERIO, vendor_values(rpc))
    return RasterioRPC(**{theirs: value for _, theirs, value in items})


def _tag_values(tag: np.ndarray) -> tuple[dict[str, float], dict[str, list[float]]]:
    """Scalars and coefficients of the 92 doubles of the RPCCoefficientTag."""
    scalars, coeffs, at = {}, {}, 0
    for name in GEOTIFF_TAG_ORDER:
        if name in COEFFS:
            coeffs[name], at = [float(v) for v in tag[at : at + N_TERMS]], at + N_TERMS
        else:
            scalars[name], at = float(tag[at]), at + 1
    return scalars, coeffs


def _accuracy(err_bias, err_rand, source: str) -> RPCAccuracy:
    """The vendor's ERR_BIAS/ERR_RAND as GDAL or the tag hold them (None, NaN, <= 0: unknown)."""
    values = []
    for value in (err_bias, err_rand):
        try:
            value = float(value)
        except (TypeError, ValueError):
            value = math.nan
        values.append(stated_value(value) if math.isfinite(value) else None)
    return RPCAccuracy(values[0], values[1], source)


def read_raster_rpc(path: str | os.PathLike, source: str) -> tuple[RPC, RPCAccuracy]:
    """RPC of a raster and its vendor's ERR_BIAS/ERR_RAND: the GeoTIFF tag when present (exact,
    sidecars ignored), else GDAL's RPC metadata (NITF TREs, sidecars, PAM)."""
    tag = read_tiff_rpc_tag(path, source)
    if tag is not None:
        scalars, coeffs = _tag_values(tag)
        rpc = assemble_rpc(scalars, coeffs, f"{source} (RPCCoefficientTag)")
        return rpc, _accuracy(scalars["err_bias"], scalars["err_rand"], source)

    from rasterio.errors import RasterioIOError

    try:  # a URL: its sidecars probed (one request each), GDAL's text of the tag (15 digits)
        with open_raster(path, sidecars=True) as src:
            rpcs = src.rpcs
    except RasterioIOError as err:
        raise RPCFormatError(f"{source}: not a readable raster or RPC file ({err})") from None
    except (KeyError, ValueError) as err:
        raise RPCFormatError(f"{source}: malformed RPC metadata ({err!r})") from None
    if rpcs is None:
        raise RPCFormatError(f"{source}: raster holds no RPC metadata")
    rpc = from_rasterio_rpc(rpcs, source)
    return rpc, _accuracy(getattr(rpcs, "err_bias", None), getattr(rpcs, "err_rand", None), source)


def _image_shape(rpc: RPC) -> tuple[int, int]:
    """(rows, cols) covering the RPC's image normalisation range ``off +- scale``."""
    values = vendor_values(rpc)
    rows = math.ceil(values["line_off"] + abs(values["line_scale"])) + 1
    cols = math.ceil(values["samp_off"] + abs(values["samp_scale"])) + 1
    return max(rows, 1), max(cols, 1)


def write_geotiff_rpc(
    rpc: RPC,
    path: str | os.PathLike,
    data: ArrayLike | None = None,
    *,
    shape: tuple[int, int] | None = None,
    overwrite: bool = False,
    update: bool = False,
) -> pathlib.Path:
    """Write ``rpc`` as GeoTIFF RPC tags (the RPCCoefficientTag, exact float64).

    New file (``update=False``): a GeoTIFF holding ``data`` (``(rows, cols)`` or
    ``(bands, rows, cols)``) or, without data, an empty sparse placeholder of ``shape`` (default:
    the RPC's image range, ``off + scale + 1`` px), tiled and a few hundred kB at most. An existing
    ``path`` is refused unless ``overwrite``.

    ``update=True`` adds the tags to the existing GeoTIFF at ``path``, keeping its pixels; if it
    already has RPC metadata (tag or sidecar) that is refused unless ``overwrite``. GDAL may
    prefer an ``.RPB``, ``_RPC.TXT`` or ``.aux.xml`` sidecar over the tag; :func:`read_rpc` on
    the GeoTIFF reads the tag.

    Either way the file is written beside ``path`` under a temporary name and renamed over it,
    so ``path`` is never left half-written. Offsets are in the RPC standard convention (ours);
    GDAL reads pixel/line = ours + 0.5.
    """
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    path = pathlib.Path(path)
    rpcs = to_rasterio_rpc(rpc)  # validates rpc before anything touches the disk
    if update:
        if data is not None or shape is not None:
            raise ValueError("write_geotiff_rpc(update=True) adds RPC tags only; drop data/shape")
        if not path.exists():
            raise FileNotFoundError(f"{path}: no GeoTIFF to add RPC tags to")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as src:
                driver, existing = src.driver, src.rpcs
        if driver != "GTiff":
            raise ValueError(f"{path}: is a {driver} raster, not a GeoTIFF")
        if existing is not None and not overwrite:
            raise FileExistsError(
                f"{path}: already holds RPC metadata; pass overwrite=True to replace it"
            )
    else:
        refuse_existing(path, overwrite)

    if not update:
        if data is None:
            rows, cols = shape if shape is not None else _image_shape(rpc)
            array, sparse = None, True
            profile = dict(count=1, dtype="uint8", height=int(rows), width=int(cols))
        else:
            array = np.asarray(data)
            array = array[None] if array.ndim == 2 else array
            if array.ndim != 3:
                raise ValueError(
                    f"data must be (rows, cols) or (bands, rows, cols), got {array.shape}"
                )
            sparse = False
            profile = dict(count=array.shape[0], dtype=array.dtype, height=array.shape[1],
                           width=array.shape[2])  # fmt: skip
    # update: the existing file was checked above and is rewritten as a whole
    with (
        atomic_output(path, overwrite or update, suffix=".tmp.tif", leftovers=[".aux.xml"]) as tmp,
        warnings.catch_warnings(),
    ):
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        if update:
            shutil.copy2(path, tmp)
            with rasterio.open(tmp, "r+") as dst:
                dst.rpcs = rpcs
        else:
            with rasterio.open(
                tmp, "w", driver="GTiff", tiled=True, blockxsize=256, blockysize=256,
                sparse_ok=sparse, rpcs=rpcs, **profile,
            ) as dst:  # fmt: skip
                if array is not None:
                    dst.write(array)
    return path
