"""XML RPC files: Airbus DIMAP (Pleiades, SPOT 6/7, Pleiades Neo) and DigitalGlobe/Maxar.

DIMAP (``RPC_*.XML``), as GDAL's DIMAP reader and rpcm read it:

- v2 (Pleiades, SPOT 6/7): ``Rational_Function_Model/Global_RFM/Inverse_Model`` holds the
  ground -> image polynomials ``SAMP_NUM_COEFF_1..20`` etc. (``Direct_Model`` is the image ->
  ground localisation model, not used here); offsets and scales in ``RFM_Validity``.
- older files without the ``Global_RFM`` level (``Rational_Function_Model/Inverse_Model``).
- v3 (Pleiades Neo): ``GroundtoImage_Values`` instead of ``Inverse_Model``.

DIMAP counts pixels from 1: the centre of the first pixel is ``(1, 1)``, so 1 is subtracted
from ``SAMP_OFF`` and ``LINE_OFF``. From v3 on the origin is stated by
``ImagetoGround_Validity_Domain/FIRST_COL`` and that value is subtracted instead (as GDAL does).
A file with only a ``Direct_Model`` is refused: it does not project ground to image.

DigitalGlobe/Maxar (WorldView, QuickBird, GeoEye) image XML: ``isd/RPB/IMAGE`` with
``LINEOFFSET`` ... ``HEIGHTSCALE`` and ``LINENUMCOEFList/LINENUMCOEF`` (20 numbers); offsets in
the RPC standard convention (ours). ``SPECID`` RPC00A selects the RPC00A term order.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from ..models.rpc import RPC
from .rpc_common import (
    RPCFormatError,
    assemble,
    parse_number,
    parse_order,
    read_coeffs,
    read_scalars,
)
from .rpc_keys import STYLES

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
    rpb = root if _local(root.tag) == "RPB" else _find(root, "RPB")
    if rpb is not None and _find(rpb, "IMAGE") is not None:
        return "maxar_xml"
    return None


def _element_lookup(elements: dict[str, ET.Element]):
    """The ``lookup`` of :func:`~jaxgeo.io.rpc_common.read_scalars` over child elements."""

    def lookup(tag: str) -> tuple[str, str] | None:
        node = elements.get(tag)
        return None if node is None else (f"<{tag}>", node.text or "")

    return lookup


def _missing_in(context: str):
    return lambda tag: f"missing <{tag}> in {context}"


def read_dimap(root: ET.Element, source: str) -> RPC:
    """Ground -> image RPC of an Airbus DIMAP RPC XML tree (see the module docstring)."""
    rfm = _find(root, "Rational_Function_Model")
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
    return assemble(scalars, coeffs, source, order=order)


def read_maxar_xml(root: ET.Element, source: str) -> RPC:
    """RPC of a DigitalGlobe/Maxar image XML tree (``RPB/IMAGE``)."""
    rpb = root if _local(root.tag) == "RPB" else _find(root, "RPB")
    image = _find(rpb, "IMAGE") if rpb is not None else None
    if image is None:
        raise RPCFormatError(f"{source}: missing <RPB><IMAGE>")
    spec = _children(rpb).get("SPECID")
    order = parse_order(spec.text if spec is not None else None, source, "<SPECID>")
    missing = _missing_in("<RPB><IMAGE>")
    scalars = read_scalars(_MAXAR, _element_lookup(_children(image)), source, missing)

    def polynomial(tag: str) -> tuple[str, str] | None:
        nodes = [e for e in image.iter() if _local(e.tag).upper() == tag]
        # one list, or one element per coefficient
        return (f"<{tag}>", " ".join(n.text or "" for n in nodes)) if nodes else None

    coeffs = read_coeffs(_MAXAR, polynomial, source, missing)
    return assemble(scalars, coeffs, source, order=order)
