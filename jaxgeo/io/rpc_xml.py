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
from .rpc_common import N_TERMS, RPCFormatError, assemble, parse_number, parse_numbers, parse_order

DIMAP_SCALARS = {
    "LINE_OFF": "line_off", "SAMP_OFF": "samp_off", "LAT_OFF": "lat_off",
    "LONG_OFF": "lon_off", "HEIGHT_OFF": "height_off", "LINE_SCALE": "line_scale",
    "SAMP_SCALE": "samp_scale", "LAT_SCALE": "lat_scale", "LONG_SCALE": "lon_scale",
    "HEIGHT_SCALE": "height_scale",
}  # fmt: skip
DIMAP_COEFFS = {
    "LINE_NUM_COEFF": "line_num", "LINE_DEN_COEFF": "line_den",
    "SAMP_NUM_COEFF": "samp_num", "SAMP_DEN_COEFF": "samp_den",
}  # fmt: skip
MAXAR_SCALARS = {
    "LINEOFFSET": "line_off", "SAMPOFFSET": "samp_off", "LATOFFSET": "lat_off",
    "LONGOFFSET": "lon_off", "HEIGHTOFFSET": "height_off", "LINESCALE": "line_scale",
    "SAMPSCALE": "samp_scale", "LATSCALE": "lat_scale", "LONGSCALE": "lon_scale",
    "HEIGHTSCALE": "height_scale",
}  # fmt: skip
MAXAR_COEFFS = {
    "LINENUMCOEF": "line_num", "LINEDENCOEF": "line_den",
    "SAMPNUMCOEF": "samp_num", "SAMPDENCOEF": "samp_den",
}  # fmt: skip


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


def _text(node: ET.Element | None, tag: str, source: str, context: str) -> str:
    if node is None:
        raise RPCFormatError(f"{source}: missing <{tag}> in {context}")
    return node.text or ""


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

    values = _children(validity)
    scalars = {}
    for tag, name in DIMAP_SCALARS.items():
        text = _text(values.get(tag), tag, source, f"<{_local(validity.tag)}>")
        scalars[name] = parse_number(text, source, f"<{tag}>")
    scalars["line_off"] -= origin
    scalars["samp_off"] -= origin

    terms = _children(model)
    coeffs = {}
    for prefix, name in DIMAP_COEFFS.items():
        coeffs[name] = []
        for i in range(1, N_TERMS + 1):
            tag = f"{prefix}_{i}"
            text = _text(terms.get(tag), tag, source, f"<{_local(model.tag)}>")
            coeffs[name].append(parse_number(text, source, f"<{tag}>"))
    return assemble(scalars, coeffs, source, order=order)


def read_maxar_xml(root: ET.Element, source: str) -> RPC:
    """RPC of a DigitalGlobe/Maxar image XML tree (``RPB/IMAGE``)."""
    rpb = root if _local(root.tag) == "RPB" else _find(root, "RPB")
    image = _find(rpb, "IMAGE") if rpb is not None else None
    if image is None:
        raise RPCFormatError(f"{source}: missing <RPB><IMAGE>")
    spec = _children(rpb).get("SPECID")
    order = parse_order(spec.text if spec is not None else None, source, "<SPECID>")
    values = _children(image)
    scalars = {}
    for tag, name in MAXAR_SCALARS.items():
        scalars[name] = parse_number(
            _text(values.get(tag), tag, source, "<RPB><IMAGE>"), source, f"<{tag}>"
        )
    coeffs = {}
    for tag, name in MAXAR_COEFFS.items():
        nodes = [e for e in image.iter() if _local(e.tag).upper() == tag]
        if not nodes:
            raise RPCFormatError(f"{source}: missing <{tag}> in <RPB><IMAGE>")
        text = " ".join(n.text or "" for n in nodes)  # one list, or one element per coefficient
        coeffs[name] = parse_numbers(text, source, f"<{tag}>")
    return assemble(scalars, coeffs, source, order=order)
