"""JSON RPC dictionaries: rpcm's, the DFC2019 / IARPA per-image JSON files, GDAL-style dicts.

The JSON files of the IEEE GRSS Data Fusion Contest 2019 (Track 3) and IARPA MVS data sets, as
Sat-NeRF and EO-NeRF write and read them, hold per image its size, footprint and, under
``"rpc"``, the RPC as rpcm's ``RPCModel.__dict__`` (``rpcm.RPCModel(d["rpc"],
dict_format="rpcm")``)::

    {"img": "JAX_068_001_RGB.tif", "height": 815, "width": 746, ...,
     "rpc": {"row_offset": 405.5, "col_offset": 371.7, "lat_offset": 30.35, "lon_offset": -81.66,
             "alt_offset": -21.0, "row_scale": ..., "alt_scale": 501.0,
             "row_num": [20 numbers], "row_den": [...], "col_num": [...], "col_den": [...]}}

rpcm evaluates the polynomials in the RPC00B order (L = lon, P = lat, H = alt) and uses the RPC
standard pixel convention, which is jaxgeo's: nothing is shifted. The same reader takes a bare
RPC dictionary (no ``"rpc"`` level) and the other spellings of :mod:`jaxgeo.io._rpc_keys` that
JSON files carry: GDAL's metadata names (``LINE_OFF``, ``LINE_NUM_COEFF``: a list or one string
of 20 numbers, e.g. rpcm's ``to_geotiff_dict``), rasterio's ``RPC.to_dict()`` (``line_off``,
``line_num_coeff``) and the ``.RPB`` names (``lineOffset``, ``lineNumCoef``). A number may be a
JSON number or a string holding one; ``NaN``, ``Infinity``, booleans, ``null``, nested values
and repeated keys are refused with :class:`RPCFormatError` naming the file and the key.
"""

from __future__ import annotations

import dataclasses
import json
import math

from ..models import RPC
from ._rpc_accuracy import RPCAccuracy, read_accuracy
from ._rpc_common import RPCFormatError, assemble_rpc, read_coeffs, read_scalars
from ._rpc_keys import ERROR_KEYS, STYLES, KeyStyle

JSON_STYLES: tuple[KeyStyle, ...] = (
    STYLES["rpcm_json"],
    STYLES["rasterio"],
    dataclasses.replace(STYLES["rpc_txt"], units=False),
    dataclasses.replace(STYLES["rpb"], list_sep=None),
)
"""The spellings a JSON RPC may use (lists are JSON arrays or whitespace-separated strings)."""
CONTAINER_KEYS = ("rpc", "RPC", "rpcs")
"""Keys under which a per-image metadata JSON nests its RPC dictionary."""


def looks_like_json(text: str) -> bool:
    return text.lstrip().startswith("{")


def _pairs(pairs: list[tuple[str, object]]) -> dict:
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"key {key!r} appears twice")
        out[key] = value
    return out


def parse_json(text: str, source: str) -> dict:
    """The top-level JSON object of ``text`` (RPCFormatError naming the line on bad JSON)."""
    try:
        root = json.loads(text, object_pairs_hook=_pairs)  # NaN/Infinity: refused with their key
    except json.JSONDecodeError as err:
        raise RPCFormatError(f"{source}: line {err.lineno}: malformed JSON ({err.msg})") from None
    except ValueError as err:
        raise RPCFormatError(f"{source}: malformed JSON ({err})") from None
    except RecursionError:
        raise RPCFormatError(f"{source}: JSON nested too deeply") from None
    if not isinstance(root, dict):
        raise RPCFormatError(f"{source}: JSON RPC file must hold an object, got {_kind(root)}")
    return root


def _kind(value: object) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list):
        return "a list"
    return type(value).__name__


def _scalar_text(value: object, source: str, where: str) -> str:
    if isinstance(value, bool) or value is None or isinstance(value, dict | list):
        raise RPCFormatError(f"{source}: {where}: expected a number, got {_kind(value)}")
    if isinstance(value, int | float):
        if isinstance(value, float) and not math.isfinite(value):
            raise RPCFormatError(f"{source}: {where}: {value!r} is not a finite number")
        return repr(value) if isinstance(value, float) else str(value)
    return str(value)


def _as_text(value: object, source: str, where: str) -> str:
    """A JSON value as the text the table-driven parser reads (lists: whitespace-separated)."""
    if isinstance(value, list):
        return " ".join(
            _scalar_text(v, source, f"{where} value {i + 1}") for i, v in enumerate(value)
        )
    return _scalar_text(value, source, where)


def _rpc_dict(root: dict, source: str) -> tuple[dict, str]:
    for key in CONTAINER_KEYS:
        if key in root:
            inner = root[key]
            if not isinstance(inner, dict):
                raise RPCFormatError(
                    f"{source}: key {key!r} must hold the RPC object, got {_kind(inner)}"
                )
            return inner, f"{key}."
    return root, ""


def _style_of(d: dict, source: str) -> KeyStyle:
    best, hits = None, 0
    for style in JSON_STYLES:
        n = sum(name in d for name in (*style.scalar_names(), *style.coeff_names()))
        if n > hits:
            best, hits = style, n
    if best is None:
        raise RPCFormatError(
            f"{source}: JSON holds no RPC keys (expected rpcm's row_offset ... col_den, or "
            "GDAL's LINE_OFF ... SAMP_DEN_COEFF)"
        )
    return best


def read_rpc_json(text: str, source: str) -> tuple[RPC, RPCAccuracy]:
    """Parse a JSON RPC dictionary (see the module docstring): its RPC and the vendor's errors
    under GDAL's names (``ERR_BIAS``/``ERR_RAND``, or rasterio's ``err_bias``/``err_rand``)."""
    d, prefix = _rpc_dict(parse_json(text, source), source)
    style = _style_of(d, source)

    def lookup(key: str) -> tuple[str, str] | None:
        if key not in d:
            return None
        where = f"key {prefix}{key}"
        return where, _as_text(d[key], source, where)

    def missing(key: str) -> str:
        return f"missing key {prefix}{key}"

    scalars = read_scalars(style, lookup, source, missing)
    rpc = assemble_rpc(scalars, read_coeffs(style, lookup, source, missing), source)
    keys = next((k for k in (ERROR_KEYS["rpc_txt"], ERROR_KEYS["rasterio"]) if k[0] in d), None)
    return rpc, read_accuracy(keys, lookup, source)


__all__ = ["JSON_STYLES", "looks_like_json", "parse_json", "read_rpc_json"]
