"""Plain-text RPC files: ``_RPC.TXT`` (key: value), ``.RPB`` (ODL groups) and OSSIM ``.geom``.

``_RPC.TXT`` — GDAL's RPC text sidecar, as delivered for Ikonos, SkySat/Planet and Cartosat-1
(whose Orthokit ``<image>_RPC_ORG.TXT`` is this layout; the product's ``_RPC.TXT`` holds the
encrypted model, which is why the NASA Ames Stereo Pipeline asks users to rename the ``_ORG``
file). One ``KEY: value [unit]`` per line; ``*_COEFF_1`` ... ``*_COEFF_20`` are 1-based and in
RPC00B order; pixel offsets follow the RPC standard (our convention)::

    LINE_OFF: 11469.5 pixels
    SAMP_OFF: 19999.5 pixels
    LAT_OFF: 43.6772638723064 degrees
    ...
    LINE_NUM_COEFF_1: -0.00185020904067451
    ...
    SAMP_DEN_COEFF_20: 5.92090135139572e-10

The 4 x 20 coefficients and 10 offsets/scales are those of 001_5627e94f1608fac0.txt section 5,
normalisation eq. 2: ``normalised = (value - offset) / scale``.

``.RPB`` — DigitalGlobe/GDAL ``BEGIN_GROUP = IMAGE ... lineNumCoef = ( ... ); END_GROUP``;
``SpecId = "RPC00A"`` selects the RPC00A term order (RPC00B otherwise).

OSSIM ``.geom`` keyword lists — ``line_off: ...``, ``line_num_coeff_00`` ... ``_19`` (0-based),
``polynomial_format: A|B`` giving the term order; pixel convention as ours.
"""

from __future__ import annotations

import os
import pathlib
import re
from collections.abc import Callable

from ..models import RPC
from ._atomic import atomic_write_text
from ._rpc_accuracy import RPCAccuracy, read_accuracy
from ._rpc_common import (
    RPCFormatError,
    assemble_rpc,
    fmt,
    parse_number,
    parse_order,
    read_coeffs,
    read_scalars,
    vendor_values,
)
from ._rpc_keys import COEFFS, ERROR_KEYS, N_TERMS, NITF_ALIASES, SCALARS, STYLES, vendor_items

# ---------------------------------------------------------------- _RPC.TXT (key: value)

_TXT = STYLES["rpc_txt"]
_INDEXED = re.compile(
    rf"({'|'.join(_TXT.coeff_names())})_(\d+)"
)  # a 1-based coefficient key, whatever its index


def _key_value_lines(
    text: str, source: str, upper: bool, relevant: Callable[[str], bool]
) -> dict[str, tuple[int, str]]:
    """``key: value`` lines -> {key: (line number, value text)}.

    A key that ``relevant`` says is read and that appears twice is an error (which value would
    be meant?); other repeated keys keep their first value.
    """
    entries: dict[str, tuple[int, str]] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        key, sep, value = stripped.partition(":")
        if not sep:
            continue  # not a key: value line (GDAL ignores these too)
        key = key.strip()
        if upper:
            key = key.upper()
            key = NITF_ALIASES.get(key, key)
        if key in entries:
            if relevant(key):
                raise RPCFormatError(
                    f"{source}: line {lineno}: key {key} repeats line {entries[key][0]}"
                )
            continue
        entries[key] = (lineno, value.strip())
    return entries


def _line_lookup(entries: dict[str, tuple[int, str]]):
    """The ``lookup`` of :func:`~jaxgeo.io._rpc_common.read_scalars` over key: value lines."""

    def lookup(key: str) -> tuple[str, str] | None:
        if key not in entries:
            return None
        lineno, value = entries[key]
        return f"line {lineno} ({key})", value

    return lookup


def _txt_relevant(key: str) -> bool:
    return (
        key in _TXT.scalar_names()
        or key in ERROR_KEYS["rpc_txt"]
        or key in _TXT.coeff_names()
        or _INDEXED.fullmatch(key) is not None
    )


def read_rpc_txt(text: str, source: str) -> tuple[RPC, RPCAccuracy]:
    """Parse a GDAL/Ikonos/SkySat/Cartosat-1 ``_RPC.TXT`` key: value file: its RPC and the
    vendor's ``ERR_BIAS``/``ERR_RAND``."""
    entries = _key_value_lines(text, source, upper=True, relevant=_txt_relevant)
    for key, (lineno, _) in entries.items():
        match = _INDEXED.fullmatch(key)
        index = match.group(2) if match else ""
        if match and (len(index) > 3 or not 1 <= int(index) <= N_TERMS):  # len: no 5000-digit int
            raise RPCFormatError(
                f"{source}: line {lineno}: {key}: coefficient index out of range 1..{N_TERMS}"
            )
    lookup = _line_lookup(entries)
    scalars = read_scalars(_TXT, lookup, source)
    rpc = assemble_rpc(scalars, read_coeffs(_TXT, lookup, source), source)
    return rpc, read_accuracy(ERROR_KEYS["rpc_txt"], lookup, source, units=True)


def format_rpc_txt(rpc: RPC, units: bool = False) -> str:
    """The ``_RPC.TXT`` text of ``rpc`` (RPC00B, full float64 precision)."""
    lines = ["ERR_BIAS: -1", "ERR_RAND: -1"]  # unknown (the NITF RPC00B convention)
    for key, name, value in vendor_items(_TXT, vendor_values(rpc)):
        unit = f" {key.unit}" if units and key.unit else ""
        lines.append(f"{name}: {fmt(value)}{unit}")
    return "\n".join(lines) + "\n"


def write_rpc_text(
    rpc: RPC, path: str | os.PathLike, *, overwrite: bool = False, units: bool = False
) -> pathlib.Path:
    """Write ``rpc`` as a ``_RPC.TXT`` key: value file (GDAL, Ikonos and Cartosat-1 layout).

    Name it ``<image>_RPC.TXT`` for GDAL to pick it up beside ``<image>.tif``. Offsets are in the
    RPC standard pixel convention (ours); GDAL reads pixel/line = ours + 0.5. Every value is
    written with the shortest text that reads back to the same float64. ``units=True`` appends
    Ikonos-style unit words (``pixels``, ``degrees``, ``meters``), which GDAL also accepts.
    The write is atomic and refuses to replace an existing file unless ``overwrite``.
    """
    return atomic_write_text(path, format_rpc_txt(rpc, units=units), overwrite=overwrite)


# ------------------------------------------------------------------------ .RPB (ODL groups)

_RPB = STYLES["rpb"]
_RPB_READ = {
    name.upper()
    for name in (*_RPB.scalar_names(), *_RPB.coeff_names(), "SpecId", *ERROR_KEYS["rpb"])
}
_ASSIGN = re.compile(r"([A-Za-z_]\w*)[ \t]*=[ \t]*")


def read_rpb(text: str, source: str) -> tuple[RPC, RPCAccuracy]:
    """Parse a DigitalGlobe/GDAL ``.RPB`` file (``name = value;`` in ``BEGIN_GROUP = IMAGE``):
    its RPC and the vendor's ``errBias``/``errRand``."""
    matches = list(_ASSIGN.finditer(text))
    items: dict[str, tuple[int, str, str]] = {}  # KEY -> (line, name as written, value text)
    for m, nxt in zip(matches, matches[1:] + [None], strict=True):
        key, lineno = m.group(1).upper(), text.count("\n", 0, m.start()) + 1
        raw = text[m.end() : nxt.start() if nxt else len(text)]
        if raw.lstrip().startswith("("):
            if ")" not in raw:
                raise RPCFormatError(
                    f"{source}: line {lineno}: list {m.group(1)} is not closed by ')' "
                    "(truncated file?)"
                )
            value = raw[raw.index("(") + 1 : raw.index(")")]
        else:
            value = raw.split(";", 1)[0].strip()
        if key in items and key in _RPB_READ:
            raise RPCFormatError(
                f"{source}: line {lineno}: {m.group(1)} repeats line {items[key][0]}"
            )
        items[key] = (lineno, m.group(1), value)

    def lookup(key: str) -> tuple[str, str] | None:
        if key.upper() not in items:
            return None
        lineno, name, value = items[key.upper()]
        return f"line {lineno} ({name})", value

    spec = items.get("SPECID")
    order = parse_order(
        spec[2] if spec else None, source, f"line {spec[0]} (SpecId)" if spec else ""
    )
    scalars = read_scalars(_RPB, lookup, source)
    rpc = assemble_rpc(scalars, read_coeffs(_RPB, lookup, source), source, order=order)
    return rpc, read_accuracy(ERROR_KEYS["rpb"], lookup, source)


def format_rpb(rpc: RPC, sat_id: str = "UNKNOWN", band_id: str = "UNKNOWN") -> str:
    """The ``.RPB`` text of ``rpc`` in GDAL's layout (RPC00B, full float64 precision)."""
    lines = [
        f'satId = "{sat_id}";',
        f'bandId = "{band_id}";',
        'SpecId = "RPC00B";',
        "BEGIN_GROUP = IMAGE",
        "\terrBias = -1;",
        "\terrRand = -1;",
    ]
    for key, name, value in vendor_items(_RPB, vendor_values(rpc)):
        if key.field in COEFFS:
            body = ",\n".join(f"\t\t\t{fmt(c)}" for c in value)
            lines.append(f"\t{name} = (\n{body});")
        else:
            lines.append(f"\t{name} = {fmt(value)};")
    lines += ["END_GROUP = IMAGE", "END;"]
    return "\n".join(lines) + "\n"


def write_rpb(
    rpc: RPC,
    path: str | os.PathLike,
    *,
    overwrite: bool = False,
    sat_id: str = "UNKNOWN",
    band_id: str = "UNKNOWN",
) -> pathlib.Path:
    """Write ``rpc`` as a DigitalGlobe/GDAL ``.RPB`` file (RPC00B term order).

    Name it ``<image>.RPB`` for GDAL to pick it up beside ``<image>.tif``. Offsets are in the RPC
    standard pixel convention (ours); GDAL reads pixel/line = ours + 0.5. Full float64 precision;
    atomic; refuses to replace an existing file unless ``overwrite``.
    """
    text = format_rpb(rpc, sat_id=sat_id, band_id=band_id)
    return atomic_write_text(path, text, overwrite=overwrite)


# ----------------------------------------------------------------- OSSIM .geom keyword list

_GEOM = STYLES["ossim_geom"]
GEOM_MARKER = re.compile(
    r"^[ \t]*([\w.]*?)(?:line|samp)_(?:num|den)_coeff_\d\d[ \t]*:", re.MULTILINE
)
"""An OSSIM coefficient key (2-digit, 0-based index); group 1 is the keyword prefix."""


def read_ossim_geom(text: str, source: str) -> tuple[RPC, RPCAccuracy]:
    """Parse an OSSIM keyword list (``.geom``) holding an ``ossimRpcModel`` (or a subclass):
    its RPC and its ``bias_error``/``rand_error`` (OTB writes 0 for unknown: read as unknown).

    Keys may carry a common prefix (``image0.line_off``). ``polynomial_format`` A or B gives the
    term order (OSSIM's A is RPC00A, B is RPC00B; B when absent). OSSIM's adjustable parameters
    (``adjustment_N.adj_param_M``) must be zero: a non-zero adjustment is refused, not ignored.
    """
    marker = GEOM_MARKER.search(text)
    prefix = marker.group(1) if marker else ""

    def relevant(key: str) -> bool:
        name = key.removeprefix(prefix)
        return (
            name in _GEOM.scalar_names()
            or name in ("polynomial_format", *ERROR_KEYS["ossim_geom"])
            or "_coeff_" in name
        )

    entries = _key_value_lines(text, source, upper=False, relevant=relevant)
    fmt_entry = entries.get(prefix + "polynomial_format")
    order = parse_order(
        fmt_entry[1] if fmt_entry else None,
        source,
        f"line {fmt_entry[0]} ({prefix}polynomial_format)" if fmt_entry else "",
    )
    _refuse_ossim_adjustment(entries, prefix, source)
    lines = _line_lookup(entries)

    def lookup(key: str) -> tuple[str, str] | None:
        return lines(prefix + key)

    def missing(key: str) -> str:
        return f"missing key {prefix}{key}"

    scalars = read_scalars(_GEOM, lookup, source, missing)
    coeffs = read_coeffs(_GEOM, lookup, source, missing)
    rpc = assemble_rpc(scalars, coeffs, source, order=order)
    return rpc, read_accuracy(ERROR_KEYS["ossim_geom"], lookup, source)


def _refuse_ossim_adjustment(entries: dict[str, tuple[int, str]], prefix: str, src: str) -> None:
    current = entries.get(prefix + "current_adjustment", (0, "0"))[1].strip() or "0"
    head = f"{prefix}adjustment_{current}.adj_param_"
    for key, (lineno, value) in entries.items():
        if key.startswith(head) and key.endswith((".parameter", ".center")):
            where = f"line {lineno} ({key})"
            if parse_number(value, src, where) != 0.0:
                raise RPCFormatError(
                    f"{src}: {where}: non-zero OSSIM adjustment {value!r} is not supported "
                    "(apply it as a jaxgeo bias instead)"
                )


__all__ = [
    "COEFFS",
    "SCALARS",
    "format_rpb",
    "format_rpc_txt",
    "read_ossim_geom",
    "read_rpb",
    "read_rpc_txt",
    "write_rpb",
    "write_rpc_text",
]
