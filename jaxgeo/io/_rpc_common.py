"""Shared pieces of the RPC readers and writers: the error type, number parsing, the
table-driven reader of :mod:`jaxgeo.io._rpc_keys`, assembly.

Every reader turns a file into the 10 offsets/scales and 4 x 20 coefficients under the vendor
names of :meth:`jaxgeo.models.RPC.from_vendor` (``line_off`` ... ``samp_den``), already in
jaxgeo's pixel convention (integer values at pixel centres, ``(0, 0)`` the centre of the first
pixel), and hands them to :func:`assemble_rpc`. A reader only says how to find a vendor key in its
file (a ``lookup``); :func:`read_scalars` and :func:`read_coeffs` walk the key table. Nothing is
ever defaulted: a missing or malformed value raises :class:`RPCFormatError` naming the file and
the key or line at fault.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from ..errors import JaxgeoError
from ..models import RPC
from ..models.internal import TermOrder, check_rpc
from ._rpc_keys import COEFFS, N_TERMS, SCALARS, KeyStyle

Lookup = Callable[[str], tuple[str, str] | None]
"""A reader's access to its file: vendor key -> ``(where, value text)``, or None if absent.
``where`` names the key (and line) for error messages."""

# A plain decimal number: optional sign, digits with an optional point, optional exponent
# (E, or Fortran's D). No "nan", "inf", hex or underscores, which float() would accept.
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][+-]?\d+)?")


class RPCFormatError(JaxgeoError, ValueError):
    """An RPC file that is not in a recognised format, is truncated, or holds a bad value.

    The message always names the file, and the key or line number at fault.
    """


def source_name(path: str | os.PathLike) -> str:
    """How error messages name a file."""
    return os.fspath(path)


def parse_number(text: str, source: str, where: str) -> float:
    """Parse one finite float64 from ``text``; ``where`` names the key/line for the error."""
    token = text.strip()
    if not _NUMBER.fullmatch(token):
        raise RPCFormatError(f"{source}: {where}: {text.strip()!r} is not a number")
    value = float(token.replace("D", "E").replace("d", "e"))
    if not math.isfinite(value):
        raise RPCFormatError(f"{source}: {where}: {token!r} overflows float64")
    return value


def is_number(text: str) -> bool:
    return _NUMBER.fullmatch(text.strip()) is not None


def parse_numbers(
    text: str, source: str, where: str, count: int = N_TERMS, sep: str | None = None
) -> list[float]:
    """Parse exactly ``count`` numbers separated by ``sep`` (whitespace when None)."""
    tokens = [t for t in text.split(sep) if t.strip()] if sep else text.split()
    if len(tokens) != count:
        raise RPCFormatError(f"{source}: {where}: {len(tokens)} values, expected {count}")
    return [parse_number(t, source, f"{where} value {i + 1}") for i, t in enumerate(tokens)]


def parse_value(text: str, source: str, where: str, units: bool = False) -> float:
    """One number; with ``units`` a trailing unit word is allowed (``11469.5 pixels``)."""
    if not units:
        return parse_number(text, source, where)
    tokens = text.split()
    if not tokens:
        raise RPCFormatError(f"{source}: {where}: no value")
    if len(tokens) > 1 and is_number(tokens[1]):
        raise RPCFormatError(f"{source}: {where}: expected one value, got {text.strip()!r}")
    return parse_number(tokens[0], source, where)


def _missing_key(key: str) -> str:
    return f"missing key {key}"


def read_scalars(
    style: KeyStyle,
    lookup: Lookup,
    source: str,
    missing: Callable[[str], str] = _missing_key,
) -> dict[str, float]:
    """The 10 scalars of :data:`~jaxgeo.io._rpc_keys.RPC_KEYS`, looked up under ``style``'s names.

    ``missing(key)`` words the error for an absent key (after ``"<source>: "``).
    """
    out = {}
    for key, name in style.scalar_names().items():
        found = lookup(key)
        if found is None:
            raise RPCFormatError(f"{source}: {missing(key)}")
        out[name] = parse_value(found[1], source, found[0], style.units)
    return out


def read_coeffs(
    style: KeyStyle,
    lookup: Lookup,
    source: str,
    missing: Callable[[str], str] = _missing_key,
) -> dict[str, list[float]]:
    """The 4 x 20 coefficients, looked up under ``style``'s names (indexed keys or lists)."""
    out: dict[str, list[float]] = {}
    for stem, name in style.coeff_names().items():
        indexed = style.first_index is not None
        if indexed and style.list_fallback and lookup(stem) is not None:
            indexed = lookup(style.indexed(stem, 0)) is not None
        if not indexed:
            found = lookup(stem)
            if found is None:
                raise RPCFormatError(f"{source}: {missing(stem)}")
            out[name] = parse_numbers(found[1], source, found[0], sep=style.list_sep)
            continue
        out[name] = []
        for i in range(N_TERMS):
            key = style.indexed(stem, i)
            found = lookup(key)
            if found is None:
                raise RPCFormatError(f"{source}: {missing(key)}")
            out[name].append(parse_value(found[1], source, found[0], style.units))
    return out


def parse_order(text: str | None, source: str, where: str) -> TermOrder:
    """``RPC00A`` / ``RPC00B`` (or OSSIM's ``A`` / ``B``); ``None`` means RPC00B."""
    if text is None:
        return "RPC00B"
    token = text.strip().strip('"').upper()
    if token in ("RPC00B", "B"):
        return "RPC00B"
    if token in ("RPC00A", "A"):
        return "RPC00A"
    raise RPCFormatError(f"{source}: {where}: unknown RPC term order {text.strip()!r}")


def assemble_rpc(
    scalars: Mapping[str, float],
    coeffs: Mapping[str, Sequence[float] | np.ndarray],
    source: str,
    order: TermOrder = "RPC00B",
) -> RPC:
    """Build and validate an :class:`~jaxgeo.models.RPC` (coefficients given in ``order``)."""
    missing = [k for k in SCALARS if k not in scalars] + [k for k in COEFFS if k not in coeffs]
    if missing:  # the format readers name their own keys first; this is the last guard
        raise RPCFormatError(f"{source}: missing RPC value(s) {', '.join(missing)}")
    for name in COEFFS:
        if len(coeffs[name]) != N_TERMS:
            raise RPCFormatError(
                f"{source}: {name} has {len(coeffs[name])} coefficients, expected {N_TERMS}"
            )
    values = {k: float(scalars[k]) for k in SCALARS}
    values.update({k: np.asarray(coeffs[k], dtype=np.float64) for k in COEFFS})
    rpc = RPC.from_vendor(**values, order=order)
    try:
        return check_rpc(rpc, source)
    except ValueError as err:
        raise RPCFormatError(str(err)) from None


def vendor_values(rpc: RPC, order: TermOrder = "RPC00B") -> dict[str, float | list[float]]:
    """The inverse of :func:`assemble_rpc`: plain Python floats under the vendor names.

    Refuses a batched RPC or one with a non-finite value or zero scale (nothing bad is written).
    """
    if np.shape(rpc.num) != (2, N_TERMS):
        raise ValueError(f"can only write a single RPC, got num of shape {np.shape(rpc.num)}")
    check_rpc(rpc, "RPC to write")
    out: dict[str, float | list[float]] = {}
    for key, value in rpc.to_vendor(order).items():
        out[key] = [float(v) for v in np.asarray(value)] if key in COEFFS else float(value)
    return out


def fmt(value: float) -> str:
    """Shortest text that reads back to the same float64 (Python's repr)."""
    return repr(float(value))
