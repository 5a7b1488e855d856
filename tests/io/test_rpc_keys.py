"""The one table of vendor RPC keys: every format's reader and writer goes through it.

Files are built here from the table alone (:func:`vendor_items`) in each vendor's layout and read
back bit-exactly by :func:`read_rpc`; the writers' files carry exactly the table's names; the
shared table-driven parser names the vendor key that is missing or bad.
"""

import inspect
import re

import numpy as np
import pytest
import rasterio

from jaxgeo import RPC, read_rpc, write_geotiff_rpc
from jaxgeo.io import RPCFormatError, from_rasterio_rpc, to_rasterio_rpc
from jaxgeo.io._rpc_common import read_coeffs, read_scalars
from jaxgeo.io._rpc_gdal import read_tiff_rpc_tag
from jaxgeo.io._rpc_keys import (
    COEFFS,
    GEOTIFF_TAG_ORDER,
    N_TERMS,
    RPC_KEYS,
    SCALARS,
    STYLES,
    vendor_items,
)
from jaxgeo.io._rpc_text import format_rpb
from jaxgeo.io.internal import detect_rpc_format, format_rpc_txt, vendor_values
from tests.io.test_rpc_formats import _awkward_rpc, assert_same_rpc

COMMA_NL = ",\n"


def _fmt(v):
    return repr(float(v))


def _values(rpc=None):
    return vendor_values(rpc if rpc is not None else _awkward_rpc())


# ------------------------------------------------------------------ the table itself


def test_table_covers_every_field_once_in_record_order():
    assert [k.field for k in RPC_KEYS] == [*SCALARS, *COEFFS]
    assert len(SCALARS) == 10 and len(COEFFS) == 4 and N_TERMS == 20
    assert set(inspect.signature(RPC.from_vendor).parameters) >= {k.field for k in RPC_KEYS}
    assert GEOTIFF_TAG_ORDER[2:] == (*SCALARS, *COEFFS)
    for style in STYLES.values():
        names = [name for _, name, _ in vendor_items(style, _values())]
        expected = 10 + 4 * (N_TERMS if style.first_index is not None else 1)
        assert len(names) == len(set(names)) == expected, style.name


@pytest.mark.parametrize("style", STYLES)
def test_shared_parser_round_trips_every_style(style):
    """Emit through the table, parse through the table: the same float64 bits."""
    style = STYLES[style]
    values = _values()
    text = {}
    for _, name, value in vendor_items(style, values):
        is_list = isinstance(value, list)
        text[name] = (style.list_sep or " ").join(map(_fmt, value)) if is_list else _fmt(value)

    def lookup(name):
        return (f"<{name}>", text[name]) if name in text else None

    scalars = read_scalars(style, lookup, "mem")
    coeffs = read_coeffs(style, lookup, "mem")
    assert scalars == {k: values[k] for k in SCALARS}
    assert coeffs == {k: values[k] for k in COEFFS}
    first = next(iter(text))
    del text[first]
    with pytest.raises(RPCFormatError, match=rf"mem: missing key {re.escape(first)}$"):
        read_scalars(style, lookup, "mem")


# -------------------------------------------- every reader, on a file built from the table


def _lines(style, values, sep=": "):
    return "\n".join(f"{n}{sep}{_fmt(v)}" for _, n, v in vendor_items(STYLES[style], values))


def _xml_elements(style, values, list_wrapper=""):
    out = []
    for key, name, value in vendor_items(STYLES[style], values):
        if key.field in COEFFS and STYLES[style].first_index is None:
            body = " ".join(_fmt(c) for c in value)
            out.append(f"<{name}{list_wrapper}><{name}>{body}</{name}></{name}{list_wrapper}>")
        else:
            out.append(f"<{name}>{_fmt(value)}</{name}>")
    return out


def _build(fmt, values):
    if fmt == "rpc_txt":
        return _lines("rpc_txt", values) + "\n"
    if fmt == "ossim_geom":
        head = "type:  ossimPleiadesModel\npolynomial_format:  B\n"
        return head + _lines("ossim_geom", values, ":  ") + "\n"
    if fmt == "rpb":
        body = [
            f"\t{name} = ({COMMA_NL.join(map(_fmt, value))});"
            if isinstance(value, list)
            else f"\t{name} = {_fmt(value)};"
            for _, name, value in vendor_items(STYLES["rpb"], values)
        ]
        body = "\n".join(body)
        return f'SpecId = "RPC00B";\nBEGIN_GROUP = IMAGE\n{body}\nEND_GROUP = IMAGE\n'
    if fmt == "maxar_xml":
        items = "".join(_xml_elements("maxar_xml", values, list_wrapper="List"))
        return f"<isd><RPB><SPECID>RPC00B</SPECID><IMAGE>{items}</IMAGE></RPB></isd>"
    if fmt == "dimap":  # DIMAP v3 stating the pixel origin 0: no shift, so bits are kept
        elements = _xml_elements("dimap", values)
        scalars, coeffs = "".join(elements[:10]), "".join(elements[10:])
        domain = "<ImagetoGround_Validity_Domain><FIRST_COL>0</FIRST_COL>"
        domain += "<FIRST_ROW>0</FIRST_ROW></ImagetoGround_Validity_Domain>"
        return (
            "<DIMAP_Document><Rational_Function_Model><Global_RFM>"
            f"<GroundtoImage_Values>{coeffs}</GroundtoImage_Values>"
            f"<RFM_Validity>{domain}{scalars}</RFM_Validity>"
            "</Global_RFM></Rational_Function_Model></DIMAP_Document>"
        )
    raise AssertionError(fmt)


TEXT_FORMATS = ["rpc_txt", "ossim_geom", "rpb", "maxar_xml", "dimap"]


@pytest.mark.parametrize("fmt", TEXT_FORMATS)
def test_every_reader_reads_a_file_built_from_the_table(real_rpcs_for_keys, tmp_path, fmt):
    for k, rpc in enumerate([_awkward_rpc(), *real_rpcs_for_keys]):
        path = tmp_path / f"{k}.rpc"
        path.write_text(_build(fmt, vendor_values(rpc)))
        assert detect_rpc_format(path) == fmt
        assert_same_rpc(read_rpc(path), rpc)


@pytest.mark.parametrize("fmt", TEXT_FORMATS)
def test_every_reader_names_a_missing_key_from_the_table(tmp_path, fmt):
    style = STYLES[fmt]
    key = RPC_KEYS[3]  # lon_off: LONG_OFF, longOffset, ...
    name = style.name_of(key)
    text = _build(fmt, _values())
    text = re.sub(rf"(?m)^\s*{name}\s*[:=].*\n|<{name}>[^<]*</{name}>", "", text)
    (tmp_path / "bad.rpc").write_text(text)
    with pytest.raises(RPCFormatError, match=rf"bad\.rpc: missing (key |<){name}\b"):
        read_rpc(tmp_path / "bad.rpc")


@pytest.fixture(scope="module")
def real_rpcs_for_keys(real_data):
    names = ["formats/rpc_IKONOS.txt", "formats/rpc_WV2.xml", "phr_ventoux__left_image.geom"]
    return [read_rpc(real_data / n) for n in names]


# ------------------------------------------------------------- every writer uses the table


def test_text_writers_write_the_table_names():
    values = _values()
    txt = format_rpc_txt(_awkward_rpc(), units=True)
    keys = re.findall(r"(?m)^(\w+): (\S+)(?: (\w+))?$", txt)[2:]  # after ERR_BIAS, ERR_RAND
    items = list(vendor_items(STYLES["rpc_txt"], values))
    assert [k for k, _, _ in keys] == [n for _, n, _ in items]
    assert [float(v) for _, v, _ in keys] == [v for _, _, v in items]
    assert [u for _, _, u in keys] == [key.unit or "" for key, _, _ in items]
    rpb = format_rpb(_awkward_rpc())
    names = re.findall(r"(?m)^\t(\w+) = ", rpb)[2:]  # after errBias, errRand
    assert names == [n for _, n, _ in vendor_items(STYLES["rpb"], values)]


def test_rasterio_and_geotiff_tag_use_the_table(tmp_path):
    rpc = _awkward_rpc()
    theirs = to_rasterio_rpc(rpc)
    for _, name, value in vendor_items(STYLES["rasterio"], _values(rpc)):
        assert getattr(theirs, name) == value
    assert_same_rpc(from_rasterio_rpc(theirs), rpc)
    write_geotiff_rpc(rpc, tmp_path / "a.tif", shape=(8, 8))
    tag = read_tiff_rpc_tag(tmp_path / "a.tif")
    at = 2
    values = _values(rpc)
    for name in GEOTIFF_TAG_ORDER[2:]:
        n = N_TERMS if name in COEFFS else 1
        assert list(tag[at : at + n]) == (values[name] if n > 1 else [values[name]])
        at += n
    assert at == len(tag) == 92
    with rasterio.open(tmp_path / "a.tif") as src:  # GDAL's own names are the table's
        tags = src.tags(ns="RPC")
    assert {k.nitf for k in RPC_KEYS} <= set(tags)
    np.testing.assert_allclose(float(tags["LONG_OFF"]), _values(rpc)["lon_off"], rtol=1e-14)
