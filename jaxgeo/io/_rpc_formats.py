"""Read an RPC from any vendor file, whatever its name; write RPB, ``_RPC.TXT`` and GeoTIFF.

:func:`read_rpc` decides the format from the content, never from the extension alone:

=============  ==========================================================================
format         recognised by
=============  ==========================================================================
``raster``     binary content (TIFF/BigTIFF, NITF, JPEG 2000 ...): GeoTIFF RPC tag, else GDAL
``dimap``      XML with ``<Rational_Function_Model>`` (Pleiades, SPOT 6/7, Pleiades Neo)
``maxar_xml``  XML with ``<RPB><IMAGE>`` (DigitalGlobe/Maxar WorldView, QuickBird, GeoEye)
``rpb``        ``BEGIN_GROUP = IMAGE`` / ``lineNumCoef = (`` (``.RPB``)
``ossim_geom`` ``line_num_coeff_00:``-style keys (OSSIM/OTB ``.geom`` keyword list)
``rpc_txt``    ``LINE_OFF:`` / ``LINE_NUM_COEFF_1:`` keys (GDAL, Ikonos, SkySat/Planet,
               Cartosat-1 ``_RPC_ORG.TXT``)
``json``       a JSON object: rpcm's dictionary (``row_offset`` ...), alone or under ``"rpc"``
               (DFC2019 / IARPA per-image files, Sat-NeRF), or GDAL-named keys
=============  ==========================================================================

Every reader returns a :class:`jaxgeo.models.RPC` in jaxgeo's pixel convention: ``(x, y) =
(samp, line)``, integer values at pixel centres, ``(0, 0)`` the centre of the first pixel. That
is the RPC standard used by RPB, ``_RPC.TXT``, GeoTIFF/NITF, Maxar XML and OSSIM; DIMAP counts
from 1 and is shifted on reading. GDAL's RPC transformer gives pixel/line = ours + 0.5.
RPC00A files are permuted into RPC00B order. Anything unreadable raises :class:`RPCFormatError`
(a ``ValueError``) naming the file and the key or line; a missing path raises
``FileNotFoundError``.

:func:`read_rpc_accuracy` reads the accuracy the vendor states beside the model (RPC00B
``ERR_BIAS``/``ERR_RAND``, m; :mod:`jaxgeo.io._rpc_accuracy`), where the format has it.
"""

from __future__ import annotations

import errno
import os
import pathlib
import re

from ..models import RPC
from ._adjusted import is_adjusted_models
from ._remote import RemotePath, as_path, is_remote, open_bytes
from ._rpc_accuracy import RPCAccuracy
from ._rpc_common import RPCFormatError, source_name
from ._rpc_gdal import read_raster_rpc, write_geotiff_rpc
from ._rpc_json import looks_like_json, parse_json, read_rpc_json
from ._rpc_text import (
    GEOM_MARKER,
    read_ossim_geom,
    read_rpb,
    read_rpc_txt,
    write_rpb,
    write_rpc_text,
)
from ._rpc_xml import parse_xml, read_dimap, read_maxar_xml, xml_kind

_RASTER_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+", b"NITF", b"NSIF")
_JP2_MAGIC = b"\x00\x00\x00\x0cjP  \r\n\x87\n"
_RPB = re.compile(r"^[ \t]*BEGIN_GROUP[ \t]*=[ \t]*IMAGE\b|\blineNumCoef[ \t]*=", re.M | re.I)
_OSSIM = re.compile(r"^[ \t]*type[ \t]*:[ \t]*ossim\w*Model\b", re.M)
_TXT = re.compile(r"^[ \t]*(?:LINE_NUM_COEFF(?:_\d+)?|LINE_OFF|SAMP_OFF)[ \t]*:", re.M | re.I)
_FORMATS = "GeoTIFF/NITF, .RPB, _RPC.TXT, OSSIM .geom, DIMAP or DigitalGlobe/Maxar XML, JSON"


def _is_binary(head: bytes) -> bool:
    return head.startswith(_RASTER_MAGIC) or head.startswith(_JP2_MAGIC) or b"\x00" in head


def _read_text(path: pathlib.Path | RemotePath) -> str:
    data = path.read_bytes()  # a URL: one GET (a model file is small)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")  # old vendor files write degree signs etc. in Latin-1


def _check_path(path: str | os.PathLike) -> pathlib.Path | RemotePath:
    path = as_path(path)
    if not is_remote(path) and not path.exists():  # a URL's absence: the server's 404
        raise FileNotFoundError(errno.ENOENT, "RPC file not found", str(path))
    return path


def _head(path: pathlib.Path | RemotePath) -> bytes | None:
    """The first 4 kB of ``path`` (a URL: one range request); ``None`` for a remote file only
    GDAL reads (``s3://``, ``gs://``, ``/vsi...``): taken for a raster."""
    if is_remote(path) and not str(path).lower().startswith(("http://", "https://")):
        return None
    with open_bytes(path) as f:
        return f.read(4096)


def _detect_text(text: str, source: str) -> str:
    if looks_like_json(text):
        return "json"
    if text.lstrip().startswith("<"):
        kind = xml_kind(parse_xml(text, source))
        if kind is None:
            raise RPCFormatError(
                f"{source}: XML file holds neither a DIMAP <Rational_Function_Model> nor a "
                "DigitalGlobe/Maxar <RPB><IMAGE>"
            )
        return kind
    if _RPB.search(text):
        return "rpb"
    if GEOM_MARKER.search(text) or _OSSIM.search(text):
        return "ossim_geom"
    if _TXT.search(text):
        return "rpc_txt"
    raise RPCFormatError(f"{source}: not a recognised RPC file (expected {_FORMATS})")


def detect_rpc_format(path: str | os.PathLike) -> str:
    """The RPC format of the file at ``path`` (see the module docstring), from its content."""
    path = _check_path(path)
    head = _head(path)
    if head is None or _is_binary(head):
        return "raster"
    return _detect_text(_read_text(path), source_name(path))


def read_rpc(path: str | os.PathLike) -> RPC:
    """Read the ground -> image RPC of any supported vendor file (format detected from content).

    Returns an :class:`~jaxgeo.models.RPC` in jaxgeo's convention (RPC standard pixel centres,
    RPC00B term order). Raises ``FileNotFoundError`` for a missing path and
    :class:`RPCFormatError` (a ``ValueError``) naming the file and the key/line at fault for an
    unknown format, a truncated file, or a missing or non-numeric value.
    """
    return read_rpc_with_accuracy(path)[0]


def read_rpc_accuracy(path: str | os.PathLike) -> RPCAccuracy:
    """The accuracy the vendor states for the RPC of the file at ``path`` (any format
    :func:`read_rpc` reads; the RPC is read and checked too): RPC00B ``ERR_BIAS`` and
    ``ERR_RAND`` in metres per horizontal axis, ``None`` each where unknown (``-1``, ``0``,
    absent, or a format without them: DIMAP, rpcm's JSON). Errors as :func:`read_rpc`."""
    return read_rpc_with_accuracy(path)[1]


def read_rpc_with_accuracy(path: str | os.PathLike) -> tuple[RPC, RPCAccuracy]:
    """:func:`read_rpc` and :func:`read_rpc_accuracy` of one read of the file."""
    path = _check_path(path)
    source = source_name(path)
    head = _head(path)
    if head is None or _is_binary(head):
        return read_raster_rpc(path, source)
    text = _read_text(path)
    kind = _detect_text(text, source)
    if kind == "dimap":  # no stated accuracy (its ERR_BIAS_ROW/COL are fit errors)
        return read_dimap(parse_xml(text, source), source), RPCAccuracy(source=source)
    if kind == "maxar_xml":
        return read_maxar_xml(parse_xml(text, source), source)
    if kind == "rpb":
        return read_rpb(text, source)
    if kind == "ossim_geom":
        return read_ossim_geom(text, source)
    if kind == "json":
        if is_adjusted_models(parse_json(text, source)):
            raise RPCFormatError(
                f"{source}: an adjusted_models.json (per image an RPC and its adjusted bias): "
                "give it as an image's model (--model IMG=FILE; jaxgeo.io.open_image(raster, "
                "model=FILE, name=IMG)); its RPC alone would leave the adjustment out"
            )
        return read_rpc_json(text, source)
    return read_rpc_txt(text, source)


__all__ = [
    "RPCFormatError",
    "detect_rpc_format",
    "read_rpc",
    "read_rpc_accuracy",
    "read_rpc_with_accuracy",
    "write_geotiff_rpc",
    "write_rpb",
    "write_rpc_text",
]
