"""Shared pieces of the RPC readers and writers: the error type, number parsing, assembly.

Every reader turns a file into the 10 offsets/scales and 4 x 20 coefficients under the vendor
names of :meth:`jaxgeo.models.RPC.from_vendor` (``line_off`` ... ``samp_den``), already in
jaxgeo's pixel convention (integer values at pixel centres, ``(0, 0)`` the centre of the first
pixel), and hands them to :func:`assemble`. Nothing is ever defaulted: a missing or malformed
value raises :class:`RPCFormatError` naming the file and the key or line at fault.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence

import numpy as np

from ..models.rpc import RPC, TermOrder, check_rpc

SCALARS = (
    "line_off", "samp_off", "lat_off", "lon_off", "height_off",
    "line_scale", "samp_scale", "lat_scale", "lon_scale", "height_scale",
)  # fmt: skip
"""The 10 normalisation constants, in the order of the RPC00B record."""
COEFFS = ("line_num", "line_den", "samp_num", "samp_den")
"""The 4 polynomials of 20 coefficients, in the order of the RPC00B record."""
N_TERMS = 20

# A plain decimal number: optional sign, digits with an optional point, optional exponent
# (E, or Fortran's D). No "nan", "inf", hex or underscores, which float() would accept.
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][+-]?\d+)?")


class RPCFormatError(ValueError):
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


def assemble(
    scalars: Mapping[str, float],
    coeffs: Mapping[str, Sequence[float]],
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
    """The inverse of :func:`assemble`: plain Python floats under the vendor names.

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
