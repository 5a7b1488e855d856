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

from ..models.rpc import RPC
from .atomic import atomic_write_text
from .rpc_common import (
    COEFFS,
    N_TERMS,
    SCALARS,
    RPCFormatError,
    assemble,
    fmt,
    is_number,
    parse_number,
    parse_numbers,
    parse_order,
    vendor_values,
)

# ---------------------------------------------------------------- _RPC.TXT (key: value)

TXT_SCALARS = {
    "LINE_OFF": "line_off", "SAMP_OFF": "samp_off", "LAT_OFF": "lat_off",
    "LONG_OFF": "lon_off", "HEIGHT_OFF": "height_off", "LINE_SCALE": "line_scale",
    "SAMP_SCALE": "samp_scale", "LAT_SCALE": "lat_scale", "LONG_SCALE": "lon_scale",
    "HEIGHT_SCALE": "height_scale",
}  # fmt: skip
TXT_COEFFS = {
    "LINE_NUM_COEFF": "line_num", "LINE_DEN_COEFF": "line_den",
    "SAMP_NUM_COEFF": "samp_num", "SAMP_DEN_COEFF": "samp_den",
}  # fmt: skip
_TXT_ALIASES = {"LON_OFF": "LONG_OFF", "LON_SCALE": "LONG_SCALE"}
_UNIT = {
    "LINE": "pixels",
    "SAMP": "pixels",
    "LAT": "degrees",
    "LONG": "degrees",
    "HEIGHT": "meters",
}
_INDEXED = re.compile(r"(LINE_NUM_COEFF|LINE_DEN_COEFF|SAMP_NUM_COEFF|SAMP_DEN_COEFF)_(\d+)")


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
            key = _TXT_ALIASES.get(key, key)
        if key in entries:
            if relevant(key):
                raise RPCFormatError(
                    f"{source}: line {lineno}: key {key} repeats line {entries[key][0]}"
                )
            continue
        entries[key] = (lineno, value.strip())
    return entries


def _scalar(entries: dict[str, tuple[int, str]], key: str, source: str) -> float:
    if key not in entries:
        raise RPCFormatError(f"{source}: missing key {key}")
    lineno, value = entries[key]
    tokens = value.split()
    where = f"line {lineno} ({key})"
    if not tokens:
        raise RPCFormatError(f"{source}: {where}: no value")
    if len(tokens) > 1 and is_number(tokens[1]):
        raise RPCFormatError(f"{source}: {where}: expected one value, got {value!r}")
    return parse_number(tokens[0], source, where)  # a trailing unit word is allowed


def _txt_relevant(key: str) -> bool:
    return key in TXT_SCALARS or key in TXT_COEFFS or _INDEXED.fullmatch(key) is not None


def read_rpc_txt(text: str, source: str) -> RPC:
    """Parse a GDAL/Ikonos/SkySat/Cartosat-1 ``_RPC.TXT`` key: value file."""
    entries = _key_value_lines(text, source, upper=True, relevant=_txt_relevant)
    for key, (lineno, _) in entries.items():
        match = _INDEXED.fullmatch(key)
        if match and not 1 <= int(match.group(2)) <= N_TERMS:
            raise RPCFormatError(
                f"{source}: line {lineno}: {key}: coefficient index out of range 1..{N_TERMS}"
            )
    scalars = {name: _scalar(entries, key, source) for key, name in TXT_SCALARS.items()}
    coeffs: dict[str, list[float]] = {}
    for key, name in TXT_COEFFS.items():
        if key in entries and f"{key}_1" not in entries:  # GDAL metadata style: 20 on one line
            lineno, value = entries[key]
            coeffs[name] = parse_numbers(value, source, f"line {lineno} ({key})")
        else:
            coeffs[name] = [_scalar(entries, f"{key}_{i}", source) for i in range(1, N_TERMS + 1)]
    return assemble(scalars, coeffs, source)


def format_rpc_txt(rpc: RPC, units: bool = False) -> str:
    """The ``_RPC.TXT`` text of ``rpc`` (RPC00B, full float64 precision)."""
    values = vendor_values(rpc)
    lines = ["ERR_BIAS: -1", "ERR_RAND: -1"]  # unknown (the NITF RPC00B convention)
    for key, name in TXT_SCALARS.items():
        unit = f" {_UNIT[key.split('_')[0]]}" if units else ""
        lines.append(f"{key}: {fmt(values[name])}{unit}")
    for key, name in TXT_COEFFS.items():
        lines += [f"{key}_{i + 1}: {fmt(c)}" for i, c in enumerate(values[name])]
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

RPB_SCALARS = {
    "LINEOFFSET": "line_off", "SAMPOFFSET": "samp_off", "LATOFFSET": "lat_off",
    "LONGOFFSET": "lon_off", "HEIGHTOFFSET": "height_off", "LINESCALE": "line_scale",
    "SAMPSCALE": "samp_scale", "LATSCALE": "lat_scale", "LONGSCALE": "lon_scale",
    "HEIGHTSCALE": "height_scale",
}  # fmt: skip
RPB_COEFFS = {
    "LINENUMCOEF": "line_num", "LINEDENCOEF": "line_den",
    "SAMPNUMCOEF": "samp_num", "SAMPDENCOEF": "samp_den",
}  # fmt: skip
_RPB_NAMES = {
    "LINEOFFSET": "lineOffset", "SAMPOFFSET": "sampOffset", "LATOFFSET": "latOffset",
    "LONGOFFSET": "longOffset", "HEIGHTOFFSET": "heightOffset", "LINESCALE": "lineScale",
    "SAMPSCALE": "sampScale", "LATSCALE": "latScale", "LONGSCALE": "longScale",
    "HEIGHTSCALE": "heightScale", "LINENUMCOEF": "lineNumCoef", "LINEDENCOEF": "lineDenCoef",
    "SAMPNUMCOEF": "sampNumCoef", "SAMPDENCOEF": "sampDenCoef",
}  # fmt: skip
_ASSIGN = re.compile(r"([A-Za-z_]\w*)[ \t]*=[ \t]*")


def read_rpb(text: str, source: str) -> RPC:
    """Parse a DigitalGlobe/GDAL ``.RPB`` file (``name = value;`` in ``BEGIN_GROUP = IMAGE``)."""
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
        if key in items and key in {**RPB_SCALARS, **RPB_COEFFS, "SPECID": None}:
            raise RPCFormatError(
                f"{source}: line {lineno}: {m.group(1)} repeats line {items[key][0]}"
            )
        items[key] = (lineno, m.group(1), value)

    def get(key: str) -> tuple[str, str]:
        if key not in items:
            raise RPCFormatError(f"{source}: missing key {_RPB_NAMES[key]}")
        lineno, name, value = items[key]
        return f"line {lineno} ({name})", value

    spec = items.get("SPECID")
    order = parse_order(
        spec[2] if spec else None, source, f"line {spec[0]} (SpecId)" if spec else ""
    )
    scalars = {}
    for key, name in RPB_SCALARS.items():
        where, value = get(key)
        scalars[name] = parse_number(value, source, where)
    coeffs = {}
    for key, name in RPB_COEFFS.items():
        where, value = get(key)
        coeffs[name] = parse_numbers(value, source, where, sep=",")
    return assemble(scalars, coeffs, source, order=order)


def format_rpb(rpc: RPC, sat_id: str = "UNKNOWN", band_id: str = "UNKNOWN") -> str:
    """The ``.RPB`` text of ``rpc`` in GDAL's layout (RPC00B, full float64 precision)."""
    values = vendor_values(rpc)
    lines = [
        f'satId = "{sat_id}";',
        f'bandId = "{band_id}";',
        'SpecId = "RPC00B";',
        "BEGIN_GROUP = IMAGE",
        "\terrBias = -1;",
        "\terrRand = -1;",
    ]
    lines += [f"\t{_RPB_NAMES[k]} = {fmt(values[n])};" for k, n in RPB_SCALARS.items()]
    for key, name in RPB_COEFFS.items():
        body = ",\n".join(f"\t\t\t{fmt(c)}" for c in values[name])
        lines.append(f"\t{_RPB_NAMES[key]} = (\n{body});")
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

GEOM_SCALARS = {
    "line_off": "line_off", "samp_off": "samp_off", "lat_off": "lat_off",
    "long_off": "lon_off", "height_off": "height_off", "line_scale": "line_scale",
    "samp_scale": "samp_scale", "lat_scale": "lat_scale", "long_scale": "lon_scale",
    "height_scale": "height_scale",
}  # fmt: skip
GEOM_COEFFS = {
    "line_num_coeff_": "line_num", "line_den_coeff_": "line_den",
    "samp_num_coeff_": "samp_num", "samp_den_coeff_": "samp_den",
}  # fmt: skip
GEOM_MARKER = re.compile(
    r"^[ \t]*([\w.]*?)(?:line|samp)_(?:num|den)_coeff_\d\d[ \t]*:", re.MULTILINE
)
"""An OSSIM coefficient key (2-digit, 0-based index); group 1 is the keyword prefix."""


def read_ossim_geom(text: str, source: str) -> RPC:
    """Parse an OSSIM keyword list (``.geom``) holding an ``ossimRpcModel`` (or a subclass).

    Keys may carry a common prefix (``image0.line_off``). ``polynomial_format`` A or B gives the
    term order (OSSIM's A is RPC00A, B is RPC00B; B when absent). OSSIM's adjustable parameters
    (``adjustment_N.adj_param_M``) must be zero: a non-zero adjustment is refused, not ignored.
    """
    marker = GEOM_MARKER.search(text)
    prefix = marker.group(1) if marker else ""

    def relevant(key: str) -> bool:
        name = key.removeprefix(prefix)
        return name in GEOM_SCALARS or name == "polynomial_format" or "_coeff_" in name

    entries = _key_value_lines(text, source, upper=False, relevant=relevant)

    def get(key: str) -> tuple[str, str]:
        full = prefix + key
        if full not in entries:
            raise RPCFormatError(f"{source}: missing key {full}")
        lineno, value = entries[full]
        return f"line {lineno} ({full})", value

    fmt_entry = entries.get(prefix + "polynomial_format")
    order = parse_order(
        fmt_entry[1] if fmt_entry else None,
        source,
        f"line {fmt_entry[0]} ({prefix}polynomial_format)" if fmt_entry else "",
    )
    _refuse_ossim_adjustment(entries, prefix, source)
    scalars = {}
    for key, name in GEOM_SCALARS.items():
        where, value = get(key)
        scalars[name] = parse_number(value, source, where)
    coeffs = {}
    for key, name in GEOM_COEFFS.items():
        coeffs[name] = []
        for i in range(N_TERMS):
            where, value = get(f"{key}{i:02d}")
            coeffs[name].append(parse_number(value, source, where))
    return assemble(scalars, coeffs, source, order=order)


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
