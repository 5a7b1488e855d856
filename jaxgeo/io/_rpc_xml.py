"""XML RPC files: Airbus DIMAP (Pleiades, SPOT 6/7, Pleiades Neo) and DigitalGlobe/Maxar.

DIMAP (``RPC_*.XML``), as GDAL's DIMAP reader and rpcm read it:

- v2 (Pleiades, SPOT 6/7): ``Rational_Function_Model/Global_RFM/Inverse_Model`` holds the
  ground -> image polynomials ``SAMP_NUM_COEFF_1..20`` etc. (``Direct_Model`` is the image ->
  ground localisation model, not used here); offsets and scales in ``RFM_Validity``.
- older files without the ``Global_RFM`` level (``Rational_Function_Model/Inverse_Model``).
- v3 (Pleiades Neo): ``GroundtoImage_Values`` instead of ``Inverse_Model``.
- v1 (Pleiades ``PHR_Dimap_Document``, METADATA_PROFILE 1.x, as OSSIM and shareloc read it):
  ``Geoposition/Rational_Sensor_Model/Global_RFM/Inverse_Model`` holds ``F_COL`` and ``F_ROW``,
  each 40 space-separated numbers (the 20 numerator then the 20 denominator coefficients, RPC00B
  order); ``RFM_Validity`` gives ``Lon``, ``Lat``, ``Alt``, ``Col``, ``Row``, each as ``A``
  (scale) and ``B`` (offset) (:data:`~jaxgeo.io._rpc_keys.DIMAP_V1_SCALARS`). When the file also
  holds the ``Direct_Model`` (``F_LON``, ``F_LAT``, image -> ground), the two are checked against
  each other: a ground point from the direct model must project back to its pixel within
  :data:`DIMAP_V1_TOLERANCE_PX`, else :class:`DimapModelsDisagreeWarning`.

DIMAP counts pixels from 1: the centre of the first pixel is ``(1, 1)``, so 1 is subtracted
from ``SAMP_OFF`` and ``LINE_OFF``. From v3 on the origin is stated by
``ImagetoGround_Validity_Domain/FIRST_COL`` and that value is subtracted instead (as GDAL does).
A file with only a ``Direct_Model`` is refused: it does not project ground to image.

DigitalGlobe/Maxar (WorldView, QuickBird, GeoEye) image XML: ``isd/RPB/IMAGE`` with
``LINEOFFSET`` ... ``HEIGHTSCALE`` and ``LINENUMCOEFList/LINENUMCOEF`` (20 numbers); offsets in
the RPC standard convention (ours). ``SPECID`` RPC00A selects the RPC00A term order.
"""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET

import numpy as np

from ..errors import JaxgeoWarning
from ..models import RPC
from ._rpc_accuracy import RPCAccuracy, read_accuracy
from ._rpc_common import (
    RPCFormatError,
    assemble_rpc,
    parse_number,
    parse_numbers,
    parse_order,
    read_coeffs,
    read_scalars,
)
from ._rpc_keys import DIMAP_V1_POLYNOMIALS, DIMAP_V1_SCALARS, ERROR_KEYS, N_TERMS, STYLES

_DIMAP = STYLES["dimap"]
_MAXAR = STYLES["maxar_xml"]


def parse_xml(text: str, source: str) -> ET.Element:
    """Parse XML text, turning a syntax error (e.g. a truncated file) into RPCFormatError."""
    try:
        return ET.fromstring(text)
    except ET.ParseError as err:
        raise RPCFormatError(f"{source}: malformed XML ({err})") from None


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _find(node: ET.Element, name: str) -> ET.Element | None:
    """First element (depth-first, the node itself included) whose local tag is ``name``."""
    return next((e for e in node.iter() if _local(e.tag) == name), None)


def _children(node: ET.Element) -> dict[str, ET.Element]:
    out: dict[str, ET.Element] = {}
    for child in node:
        out.setdefault(_local(child.tag).upper(), child)
    return out


def xml_kind(root: ET.Element) -> str | None:
    """``"dimap"``, ``"maxar_xml"`` or None for an XML tree that holds neither RPC layout."""
    if _find(root, "Rational_Function_Model") is not None:
        return "dimap"
    if _find(root, "Rational_Sensor_Model") is not None:
        return "dimap"  # DIMAP v1
    rpb = root if _local(root.tag) == "RPB" else _find(root, "RPB")
    if rpb is not None and _find(rpb, "IMAGE") is not None:
        return "maxar_xml"
    return None


def _element_lookup(elements: dict[str, ET.Element]):
    """The ``lookup`` of :func:`~jaxgeo.io._rpc_common.read_scalars` over child elements."""

    def lookup(tag: str) -> tuple[str, str] | None:
        node = elements.get(tag)
        return None if node is None else (f"<{tag}>", node.text or "")

    return lookup


def _missing_in(context: str):
    return lambda tag: f"missing <{tag}> in {context}"


def read_dimap(root: ET.Element, source: str) -> RPC:
    """Ground -> image RPC of an Airbus DIMAP RPC XML tree (see the module docstring)."""
    rfm = _find(root, "Rational_Function_Model")
    if rfm is None and _find(root, "Rational_Sensor_Model") is not None:
        return read_dimap_v1(root, source)
    if rfm is None:
        raise RPCFormatError(f"{source}: missing <Rational_Function_Model>")
    model = _find(rfm, "Inverse_Model")
    if model is None:
        model = _find(rfm, "GroundtoImage_Values")
    if model is None:
        found = "only a <Direct_Model> (image -> ground)" if _find(rfm, "Direct_Model") else "no"
        raise RPCFormatError(
            f"{source}: DIMAP file has {found} RFM; the ground -> image model "
            "<Inverse_Model> / <GroundtoImage_Values> is missing"
        )
    validity = _find(rfm, "RFM_Validity")
    validity = rfm if validity is None else validity
    ref = _find(rfm, "RESOURCE_ID")
    order = parse_order(
        ref.text if ref is not None and (ref.text or "").strip() in ("RPC00A", "RPC00B") else None,
        source,
        "<RESOURCE_ID>",
    )
    origin = 1.0  # DIMAP v1/v2: the centre of the first pixel is (1, 1)
    domain = _find(root, "ImagetoGround_Validity_Domain")
    first_col = _find(domain, "FIRST_COL") if domain is not None else None
    if first_col is not None:
        origin = parse_number(first_col.text or "", source, "<FIRST_COL>")

    scalars = read_scalars(
        _DIMAP,
        _element_lookup(_children(validity)),
        source,
        _missing_in(f"<{_local(validity.tag)}>"),
    )
    scalars["line_off"] -= origin
    scalars["samp_off"] -= origin
    coeffs = read_coeffs(
        _DIMAP, _element_lookup(_children(model)), source, _missing_in(f"<{_local(model.tag)}>")
    )
    return assemble_rpc(scalars, coeffs, source, order=order)


class DimapModelsDisagreeWarning(JaxgeoWarning):
    """A DIMAP file's direct (image -> ground) and inverse (ground -> image) models disagree."""


DIMAP_V1_TOLERANCE_PX = 1.0
"""Largest accepted disagreement of a DIMAP v1 file's direct and inverse models (px). Both are
fits of one physical model, published with ``MODEL_PRECISION`` of ~1e-3 px; shareloc's test of
this round trip allows 2e-2 px. A disagreement of a pixel means a corrupt or mismatched file."""


def _text_of(node: ET.Element, path: tuple[str, ...], source: str) -> tuple[str, str]:
    """``(where, text)`` of the element reached through the local tags ``path``."""
    for tag in path:
        child = next((c for c in node if _local(c.tag) == tag), None)
        if child is None:
            where = "/".join(path[: path.index(tag) + 1])
            raise RPCFormatError(f"{source}: missing <{where}> in the DIMAP v1 <Global_RFM>")
        node = child
    return "<" + "/".join(path) + ">", node.text or ""


def read_dimap_v1(root: ET.Element, source: str) -> RPC:
    """Ground -> image RPC of an Airbus DIMAP v1 (``PHR_Dimap_Document``) tree."""
    rfm = _find(_find(root, "Rational_Sensor_Model"), "Global_RFM")
    if rfm is None:
        raise RPCFormatError(f"{source}: missing <Global_RFM> in <Rational_Sensor_Model>")
    scalars = {
        field: _number(rfm, ("RFM_Validity", *path), source)
        for field, path in DIMAP_V1_SCALARS.items()
    }
    polys = {}
    for tag, (model, num, den) in DIMAP_V1_POLYNOMIALS.items():
        if model == "Direct_Model" and _find(rfm, "Direct_Model") is None:
            continue  # optional: only used to cross-check
        where, text = _text_of(rfm, (model, tag), source)
        values = parse_numbers(text, source, where, count=2 * N_TERMS)
        polys[num], polys[den] = values[:N_TERMS], values[N_TERMS:]
    rpc_1 = assemble_rpc(scalars, polys, source)  # DIMAP pixels: (1, 1) is the first pixel's centre
    if "lon_num" in polys:
        _check_direct_model(rpc_1, scalars, polys, source)
    scalars["line_off"] -= 1.0
    scalars["samp_off"] -= 1.0
    return assemble_rpc(scalars, polys, source)


def _number(node: ET.Element, path: tuple[str, ...], source: str) -> float:
    where, text = _text_of(node, path, source)
    return parse_number(text, source, where)


def _rational(num, den, normalized: np.ndarray) -> np.ndarray:
    lon, lat, h = normalized.T
    terms = np.stack(
        [
            np.ones_like(lon),
            lon,
            lat,
            h,
            lon * lat,
            lon * h,
            lat * h,
            lon * lon,
            lat * lat,
            h * h,
            lat * lon * h,
            lon**3,
            lon * lat**2,
            lon * h**2,
            lon**2 * lat,
            lat**3,
            lat * h**2,
            lon**2 * h,
            lat**2 * h,
            h**3,
        ],
        axis=-1,
    )  # fmt: skip  (RPC00B order, jaxgeo.models._rpc.RPC00B_TERMS)
    with np.errstate(all="ignore"):
        return (terms @ np.asarray(num)) / (terms @ np.asarray(den))


def _check_direct_model(rpc_1: RPC, s: dict, polys: dict, source: str) -> None:
    """Warn when ground points of the direct model do not project back to their pixels."""
    u = np.linspace(-0.9, 0.9, 5)
    cc, rr, hh = (v.ravel() for v in np.meshgrid(u, u, [-0.9, 0.0, 0.9], indexing="ij"))
    image_n = np.stack([cc, rr, hh], -1)  # normalised (col, row, h)
    lon = _rational(polys["lon_num"], polys["lon_den"], image_n) * s["lon_scale"] + s["lon_off"]
    lat = _rational(polys["lat_num"], polys["lat_den"], image_n) * s["lat_scale"] + s["lat_off"]
    h = hh * s["height_scale"] + s["height_off"]
    ground_n = (np.stack([lon, lat, h], -1) - np.asarray(rpc_1.ground_offset)) / np.asarray(
        rpc_1.ground_scale
    )
    num, den = np.asarray(rpc_1.num), np.asarray(rpc_1.den)
    xy = np.stack([_rational(num[i], den[i], ground_n) for i in range(2)], -1)
    xy = xy * np.asarray(rpc_1.image_scale) + np.asarray(rpc_1.image_offset)
    pixel = np.stack([cc * s["samp_scale"] + s["samp_off"], rr * s["line_scale"] + s["line_off"]])
    err = np.abs(xy - pixel.T)
    worst = float(np.max(err)) if np.all(np.isfinite(err)) else float("inf")
    if not worst <= DIMAP_V1_TOLERANCE_PX:
        warnings.warn(
            f"{source}: the DIMAP v1 direct model (F_LON, F_LAT) and inverse model (F_COL, "
            f"F_ROW) disagree by up to {worst:.3g} px (more than {DIMAP_V1_TOLERANCE_PX} px): "
            "corrupt or mismatched coefficients? The inverse model is used.",
            DimapModelsDisagreeWarning,
            stacklevel=4,
        )


def read_maxar_xml(root: ET.Element, source: str) -> tuple[RPC, RPCAccuracy]:
    """RPC of a DigitalGlobe/Maxar image XML tree (``RPB/IMAGE``) and the vendor's
    ``<ERRBIAS>``/``<ERRRAND>``."""
    rpb = root if _local(root.tag) == "RPB" else _find(root, "RPB")
    image = _find(rpb, "IMAGE") if rpb is not None else None
    if image is None:
        raise RPCFormatError(f"{source}: missing <RPB><IMAGE>")
    spec = _children(rpb).get("SPECID")
    order = parse_order(spec.text if spec is not None else None, source, "<SPECID>")
    missing = _missing_in("<RPB><IMAGE>")
    lookup = _element_lookup(_children(image))
    scalars = read_scalars(_MAXAR, lookup, source, missing)

    def polynomial(tag: str) -> tuple[str, str] | None:
        nodes = [e for e in image.iter() if _local(e.tag).upper() == tag]
        # one list, or one element per coefficient
        return (f"<{tag}>", " ".join(n.text or "" for n in nodes)) if nodes else None

    coeffs = read_coeffs(_MAXAR, polynomial, source, missing)
    rpc = assemble_rpc(scalars, coeffs, source, order=order)
    return rpc, read_accuracy(ERROR_KEYS["maxar_xml"], lookup, source)
