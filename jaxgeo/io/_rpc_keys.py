"""The one table of RPC keys: jaxgeo's field names and every vendor's names for them.

An RPC is 10 normalisation constants and 4 polynomials of 20 coefficients (001_5627e94f1608fac0.txt
section 5, eq. 1-2: ``normalised = (value - offset) / scale``). Our field names are those of
:meth:`jaxgeo.models.RPC.from_vendor` (``line_off`` ... ``samp_den``). Vendors spell them in two
families, from which every format's keys are derived (:data:`STYLES`):

==============  ====================  ===============================================
style           spelling              coefficients
==============  ====================  ===============================================
``rpc_txt``     ``LINE_OFF``          ``LINE_NUM_COEFF_1`` .. ``_20`` (or one list)
``dimap``       ``LINE_OFF``          ``<LINE_NUM_COEFF_1>`` .. ``_20`` (DIMAP v1-v3)
``ossim_geom``  ``line_off``          ``line_num_coeff_00`` .. ``_19``
``rasterio``    ``line_off``          ``line_num_coeff`` (a list; GDAL's Python names)
``rpb``         ``lineOffset``        ``lineNumCoef = ( .., .. )`` (comma list)
``maxar_xml``   ``LINEOFFSET``        ``<LINENUMCOEF>`` (whitespace list)
``rpcm_json``   ``row_offset``        ``"row_num": [..]`` (rpcm / Sat-NeRF / DFC2019 JSON)
==============  ====================  ===============================================

The first family is NITF RPC00B's (GDAL's RPC metadata, ``_RPC.TXT``, DIMAP, OSSIM lower-cased);
the second DigitalGlobe's ``.RPB`` (upper-cased in Maxar XML). The GeoTIFF RPCCoefficientTag holds
the same values as 92 doubles in :data:`GEOTIFF_TAG_ORDER`. rpcm (and the JSON files of the
DFC2019 / IARPA data sets as Sat-NeRF writes them) names the fields ``row_offset`` ...
``col_den`` (:attr:`RPCKey.rpcm`).
Airbus DIMAP v1 (``PHR_Dimap_Document``) follows neither family: :data:`DIMAP_V1_SCALARS` and
:data:`DIMAP_V1_POLYNOMIALS`. Readers look keys up through
:meth:`KeyStyle.scalar_names` / :meth:`KeyStyle.coeff_names`, writers emit
:func:`vendor_items`; nothing else spells a vendor key.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping, Sequence
from typing import Literal, NamedTuple


class RPCKey(NamedTuple):
    """One RPC field: our name, its NITF/GDAL and its RPB spelling, and its unit word."""

    field: str
    """jaxgeo's name (a keyword of :meth:`jaxgeo.models.RPC.from_vendor`)."""
    nitf: str
    """NITF RPC00B / GDAL / ``_RPC.TXT`` / DIMAP name (OSSIM and rasterio lower-case it)."""
    rpb: str
    """DigitalGlobe ``.RPB`` name (Maxar XML upper-cases it)."""
    unit: str | None
    """Unit word of Ikonos-style ``_RPC.TXT`` files (None for coefficients)."""
    rpcm: str = ""
    """rpcm's attribute name (``row_offset`` ... ``col_den``): its ``RPCModel.__dict__``, the
    ``"rpc"`` dictionary of the DFC2019 / IARPA JSON files that Sat-NeRF and rpcm read."""


RPC_KEYS: tuple[RPCKey, ...] = (
    RPCKey("line_off", "LINE_OFF", "lineOffset", "pixels", "row_offset"),
    RPCKey("samp_off", "SAMP_OFF", "sampOffset", "pixels", "col_offset"),
    RPCKey("lat_off", "LAT_OFF", "latOffset", "degrees", "lat_offset"),
    RPCKey("lon_off", "LONG_OFF", "longOffset", "degrees", "lon_offset"),
    RPCKey("height_off", "HEIGHT_OFF", "heightOffset", "meters", "alt_offset"),
    RPCKey("line_scale", "LINE_SCALE", "lineScale", "pixels", "row_scale"),
    RPCKey("samp_scale", "SAMP_SCALE", "sampScale", "pixels", "col_scale"),
    RPCKey("lat_scale", "LAT_SCALE", "latScale", "degrees", "lat_scale"),
    RPCKey("lon_scale", "LONG_SCALE", "longScale", "degrees", "lon_scale"),
    RPCKey("height_scale", "HEIGHT_SCALE", "heightScale", "meters", "alt_scale"),
    RPCKey("line_num", "LINE_NUM_COEFF", "lineNumCoef", None, "row_num"),
    RPCKey("line_den", "LINE_DEN_COEFF", "lineDenCoef", None, "row_den"),
    RPCKey("samp_num", "SAMP_NUM_COEFF", "sampNumCoef", None, "col_num"),
    RPCKey("samp_den", "SAMP_DEN_COEFF", "sampDenCoef", None, "col_den"),
)
"""Every field, in the order of the NITF RPC00B record (10 scalars, then 4 polynomials)."""

N_SCALARS = 10
N_TERMS = 20
"""Coefficients per polynomial."""
SCALAR_KEYS = RPC_KEYS[:N_SCALARS]
COEFF_KEYS = RPC_KEYS[N_SCALARS:]
SCALARS = tuple(k.field for k in SCALAR_KEYS)
"""The 10 normalisation constants, in the order of the RPC00B record."""
COEFFS = tuple(k.field for k in COEFF_KEYS)
"""The 4 polynomials of 20 coefficients, in the order of the RPC00B record."""

NITF_ALIASES = {"LON_OFF": "LONG_OFF", "LON_SCALE": "LONG_SCALE"}
"""Other spellings some ``_RPC.TXT`` writers use (read, never written)."""
GEOTIFF_TAG_ORDER = ("err_bias", "err_rand", *SCALARS, *COEFFS)
"""Layout of the 92 doubles of the GeoTIFF RPCCoefficientTag (coefficients 20 each)."""

Spelling = Literal["nitf", "nitf_lower", "rpb", "rpb_upper", "rpcm"]


@dataclasses.dataclass(frozen=True)
class KeyStyle:
    """How one vendor format names the fields of :data:`RPC_KEYS`.

    ``first_index`` None: each polynomial is one key holding 20 values separated by
    ``list_sep`` (whitespace when None). Otherwise one key per coefficient,
    ``<name>_<i>`` with ``i`` from ``first_index``, zero-padded to ``index_digits``.
    ``list_fallback``: a polynomial may also be one list (GDAL metadata style).
    ``units``: a value may be followed by a unit word (``LINE_OFF: 11469.5 pixels``).
    """

    name: str
    spelling: Spelling
    first_index: int | None = None
    index_digits: int = 1
    list_sep: str | None = None
    list_fallback: bool = False
    units: bool = False

    def name_of(self, key: RPCKey) -> str:
        """The vendor name of ``key`` (of a polynomial: its stem, without an index)."""
        if self.spelling == "nitf":
            return key.nitf
        if self.spelling == "nitf_lower":
            return key.nitf.lower()
        if self.spelling == "rpb":
            return key.rpb
        if self.spelling == "rpcm":
            return key.rpcm
        return key.rpb.upper()

    def indexed(self, stem: str, i: int) -> str:
        """Name of the coefficient ``i`` (0-based, RPC00B order) of the polynomial ``stem``."""
        if self.first_index is None:
            raise ValueError(f"{self.name}: polynomials are lists, not indexed keys")
        return f"{stem}_{i + self.first_index:0{self.index_digits}d}"

    def scalar_names(self) -> dict[str, str]:
        """``{vendor name: field}`` of the 10 scalars, in record order."""
        return {self.name_of(k): k.field for k in SCALAR_KEYS}

    def coeff_names(self) -> dict[str, str]:
        """``{vendor stem: field}`` of the 4 polynomials, in record order."""
        return {self.name_of(k): k.field for k in COEFF_KEYS}


STYLES: Mapping[str, KeyStyle] = {
    s.name: s
    for s in (
        KeyStyle("rpc_txt", "nitf", first_index=1, list_fallback=True, units=True),
        KeyStyle("dimap", "nitf", first_index=1),
        KeyStyle("ossim_geom", "nitf_lower", first_index=0, index_digits=2),
        KeyStyle("rasterio", "nitf_lower"),
        KeyStyle("rpb", "rpb", list_sep=","),
        KeyStyle("maxar_xml", "rpb_upper"),
        KeyStyle("rpcm_json", "rpcm"),
    )
}
"""Every vendor style, by the format name :func:`jaxgeo.io.detect_rpc_format` gives."""

ERROR_KEYS: Mapping[str, tuple[str, str] | None] = {
    "rpc_txt": ("ERR_BIAS", "ERR_RAND"),
    "dimap": None,  # its ERR_BIAS_ROW/COL are the rational functions' fit errors, not these
    "ossim_geom": ("bias_error", "rand_error"),
    "rasterio": ("err_bias", "err_rand"),
    "rpb": ("errBias", "errRand"),
    "maxar_xml": ("ERRBIAS", "ERRRAND"),
    "rpcm_json": None,
}
"""Per style, the names of the vendor's stated errors ``(ERR_BIAS, ERR_RAND)`` (m per
horizontal axis; :mod:`jaxgeo.io._rpc_accuracy`), ``None`` where the format has none. The
GeoTIFF tag holds them as its first two doubles (:data:`GEOTIFF_TAG_ORDER`)."""


DIMAP_V1_SCALARS: Mapping[str, tuple[str, str]] = {
    "lon_off": ("Lon", "B"),
    "lon_scale": ("Lon", "A"),
    "lat_off": ("Lat", "B"),
    "lat_scale": ("Lat", "A"),
    "height_off": ("Alt", "B"),
    "height_scale": ("Alt", "A"),
    "samp_off": ("Col", "B"),
    "samp_scale": ("Col", "A"),
    "line_off": ("Row", "B"),
    "line_scale": ("Row", "A"),
}
"""DIMAP v1 ``RFM_Validity``: ``field -> (element, child)``; ``value = A * normalised + B``
(A the scale, B the offset; image offsets count from 1)."""
DIMAP_V1_POLYNOMIALS: Mapping[str, tuple[str, str, str]] = {
    "F_COL": ("Inverse_Model", "samp_num", "samp_den"),
    "F_ROW": ("Inverse_Model", "line_num", "line_den"),
    "F_LON": ("Direct_Model", "lon_num", "lon_den"),
    "F_LAT": ("Direct_Model", "lat_num", "lat_den"),
}
"""DIMAP v1 ``Global_RFM`` lists: ``element -> (model, numerator, denominator)``; each holds 40
numbers, the 20 numerator then the 20 denominator coefficients, RPC00B order. The direct (image
-> ground) polynomials take normalised ``(col, row, h)`` where the inverse ones take
``(lon, lat, h)``."""


def vendor_items(
    style: KeyStyle, values: Mapping[str, float | Sequence[float]]
) -> Iterator[tuple[RPCKey, str, float | Sequence[float]]]:
    """``(key, vendor name, value)`` in record order, as a writer of ``style`` emits them.

    ``values`` maps our field names to numbers (polynomials: 20 each); an indexed style gives
    one item per coefficient, a list style one item per polynomial.
    """
    for key in SCALAR_KEYS:
        yield key, style.name_of(key), values[key.field]
    for key in COEFF_KEYS:
        stem = style.name_of(key)
        if style.first_index is None:
            yield key, stem, values[key.field]
        else:
            for i, c in enumerate(values[key.field]):
                yield key, style.indexed(stem, i), c


__all__ = [
    "COEFFS",
    "DIMAP_V1_POLYNOMIALS",
    "DIMAP_V1_SCALARS",
    "ERROR_KEYS",
    "GEOTIFF_TAG_ORDER",
    "N_TERMS",
    "RPC_KEYS",
    "SCALARS",
    "STYLES",
    "KeyStyle",
    "RPCKey",
    "vendor_items",
]
