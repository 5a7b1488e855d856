"""Real deliveries: Pleiades DIMAP v1, DFC2019 / IARPA JSON RPCs, antimeridian, zero denominators.

Fixtures and provenance: tests/io/data/README.md. Reference values come from other projects' test
suites, cited where used (shareloc, rpcm, GDAL autotest).
"""

import dataclasses
import json
import pathlib
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.optimize import brentq

from jaxgeo import RPC, read_rpc
from jaxgeo.io import RPCFormatError
from jaxgeo.io._rpc_json import JSON_STYLES
from jaxgeo.io._rpc_keys import COEFFS, vendor_items
from jaxgeo.io._rpc_xml import DimapModelsDisagreeWarning
from jaxgeo.io.internal import detect_rpc_format, vendor_values

DATA = pathlib.Path(__file__).parent / "data"
DIMAP_V1 = DATA / "PHRDIMAP_P1BP--2018122638935449CP.XML"
JAX_JSON = DATA / "JAX_068_001_RGB.json"


def _poly_xyz(c, x, y, z):
    """A cubic in the monomial order shareloc and rpcm write out term by term
    (1, x, y, z, xy, xz, yz, xx, yy, zz, xyz, xxx, xyy, xzz, xxy, yyy, yzz, xxz, yyz, zzz)."""
    return (
        c[0] + c[1] * x + c[2] * y + c[3] * z + c[4] * x * y + c[5] * x * z + c[6] * y * z
        + c[7] * x * x + c[8] * y * y + c[9] * z * z + c[10] * x * y * z + c[11] * x**3
        + c[12] * x * y * y + c[13] * x * z * z + c[14] * x * x * y + c[15] * y**3
        + c[16] * y * z * z + c[17] * x * x * z + c[18] * y * y * z + c[19] * z**3
    )  # fmt: skip


# ---------------------------------------------------------------------------- DIMAP v1


def _dimap_v1_lists(path=DIMAP_V1):
    """An independent minimal parse of the DIMAP v1 file (as shareloc's rpc_reader_dimap_v1)."""
    root = ET.parse(path).getroot()
    rfm = root.find("Geoposition/Rational_Sensor_Model/Global_RFM")
    lists = {t: [float(v) for v in rfm.find(f".//{t}").text.split()] for t in ("F_LON", "F_LAT")}
    lists |= {t: [float(v) for v in rfm.find(f".//{t}").text.split()] for t in ("F_COL", "F_ROW")}
    val = rfm.find("RFM_Validity")
    ab = {n: (float(val.find(f"{n}/A").text), float(val.find(f"{n}/B").text))
          for n in ("Lon", "Lat", "Alt", "Col", "Row")}  # fmt: skip
    return lists, ab


def test_dimap_v1_reads_the_inverse_model_shifted_to_our_pixels():
    assert detect_rpc_format(DIMAP_V1) == "dimap"
    rpc = read_rpc(DIMAP_V1)
    lists, ab = _dimap_v1_lists()
    v = vendor_values(rpc)
    assert v["samp_num"] == lists["F_COL"][:20] and v["samp_den"] == lists["F_COL"][20:]
    assert v["line_num"] == lists["F_ROW"][:20] and v["line_den"] == lists["F_ROW"][20:]
    # DIMAP counts pixels from 1: ours = DIMAP - 1 (OSSIM and shareloc subtract 1 too)
    assert v["samp_off"] == ab["Col"][1] - 1.0 == 19999.5
    assert v["line_off"] == ab["Row"][1] - 1.0 == 19123.5
    assert (v["samp_scale"], v["line_scale"]) == (ab["Col"][0], ab["Row"][0])
    assert (v["lon_off"], v["lon_scale"]) == (ab["Lon"][1], ab["Lon"][0])
    assert (v["lat_off"], v["lat_scale"]) == (ab["Lat"][1], ab["Lat"][0])
    # shareloc tests/geomodels/test_rpc.py::test_rpc_minmax on this file: get_alt_min_max gives
    # 532.5 .. 617.5, which shareloc computes as height offset -+ scale / 2 (Alt B -+ A / 2)
    h_off, h_scale = v["height_off"], v["height_scale"]
    assert (h_off - h_scale / 2, h_off + h_scale / 2) == (532.5, 617.5)


@pytest.mark.parametrize("col,row,alt", [(600.0, 200.0, 125.0), (20000.0, 19000.0, 575.0)])
def test_dimap_v1_direct_model_round_trip(col, row, alt):
    """shareloc test_rpc_phrdimap: direct model at (col 600, row 200, alt 125), in shareloc's
    top-left-corner convention (= ours + 0.5), back through the inverse model within 2e-2 px."""
    rpc = read_rpc(DIMAP_V1)
    lists, ab = _dimap_v1_lists()
    ours = np.array([col - 0.5, row - 0.5])
    # the direct model takes normalised (col, row, alt) in DIMAP's 1-based pixels
    cn = (ours[0] + 1.0 - ab["Col"][1]) / ab["Col"][0]
    rn = (ours[1] + 1.0 - ab["Row"][1]) / ab["Row"][0]
    an = (alt - ab["Alt"][1]) / ab["Alt"][0]

    def rational(c):
        return _poly_xyz(c[:20], cn, rn, an) / _poly_xyz(c[20:], cn, rn, an)

    lon = rational(lists["F_LON"]) * ab["Lon"][0] + ab["Lon"][1]
    lat = rational(lists["F_LAT"]) * ab["Lat"][0] + ab["Lat"][1]
    back = np.asarray(rpc.project(np.array([lon, lat, alt])))
    print(f"direct -> inverse round trip: {np.abs(back - ours).max():.2e} px")
    np.testing.assert_allclose(back, ours, atol=2e-2)


def test_dimap_v1_errors_and_cross_check(tmp_path):
    text = DIMAP_V1.read_text()
    bad = tmp_path / "v1.XML"
    bad.write_text(re.sub(r"<F_ROW>.*?</F_ROW>", "", text, flags=re.S))
    with pytest.raises(RPCFormatError, match=r"v1\.XML: missing <Inverse_Model/F_ROW>"):
        read_rpc(bad)
    bad.write_text(text.replace("<F_COL>0.00235024480185869 ", "<F_COL>"))
    with pytest.raises(RPCFormatError, match=r"v1\.XML: <Inverse_Model/F_COL>: 39 values, exp"):
        read_rpc(bad)
    bad.write_text(text.replace("<B>20000.5</B>", "<B>20000.5 px</B>"))
    with pytest.raises(RPCFormatError, match=r"<RFM_Validity/Col/B>: '20000.5 px' is not a num"):
        read_rpc(bad)
    # a direct model that disagrees with the inverse one (e.g. a swapped coefficient) is named
    bad.write_text(text.replace("<F_LON>-0.00234038083880009 0.997", "<F_LON>-0.0234038 0.997"))
    with pytest.warns(DimapModelsDisagreeWarning, match=r"v1\.XML: .* disagree by up to"):
        rpc = read_rpc(bad)
    assert np.array_equal(np.asarray(rpc.num), np.asarray(read_rpc(DIMAP_V1).num))
    # the direct model is optional
    bad.write_text(re.sub(r"<Direct_Model>.*?</Direct_Model>", "", text, flags=re.S))
    assert np.array_equal(np.asarray(read_rpc(bad).den), np.asarray(read_rpc(DIMAP_V1).den))


# ---------------------------------------------------------------------- JSON dictionaries


def test_dfc2019_json_reads_rpcm_dictionary_without_shift():
    assert detect_rpc_format(JAX_JSON) == "json"
    rpc = read_rpc(JAX_JSON)
    d = json.loads(JAX_JSON.read_text())["rpc"]
    v = vendor_values(rpc)
    assert (v["samp_off"], v["line_off"]) == (d["col_offset"], d["row_offset"])
    assert (v["lon_off"], v["lat_off"], v["height_off"]) == (
        d["lon_offset"], d["lat_offset"], d["alt_offset"])  # fmt: skip
    assert v["line_num"] == d["row_num"] and v["samp_den"] == d["col_den"]
    # rpcm's RPCModel.projection, written out independently: apply_poly(poly, x=lat, y=lon, z)
    lon = d["lon_offset"] + d["lon_scale"] * np.array([-0.9, 0.0, 0.7])
    lat = d["lat_offset"] + d["lat_scale"] * np.array([0.5, 0.0, -0.8])
    alt = np.array([-27.0, 0.0, 30.0])
    nlon, nlat = (lon - d["lon_offset"]) / d["lon_scale"], (lat - d["lat_offset"]) / d["lat_scale"]
    nalt = (alt - d["alt_offset"]) / d["alt_scale"]

    def rfm(num, den):  # rpcm's term order is RPC00B: 1, L, P, H, LP, ... in y=lon, x=lat
        return _poly_xyz(num, nlon, nlat, nalt) / _poly_xyz(den, nlon, nlat, nalt)

    col = rfm(d["col_num"], d["col_den"]) * d["col_scale"] + d["col_offset"]
    row = rfm(d["row_num"], d["row_den"]) * d["row_scale"] + d["row_offset"]
    ours = np.asarray(rpc.project(np.stack([lon, lat, alt], -1)))
    np.testing.assert_allclose(ours, np.stack([col, row], -1), rtol=0, atol=1e-9)


def test_dfc2019_json_footprint_is_consistent():
    """The file's own footprint (Sat-NeRF: rpc.localization of the corners (0, 0), (w, 0),
    (w, h), (0, h) at one SRTM height): with the height solved from the first corner's column,
    every corner's column comes back within 0.02 px, and the rows share one offset (~1.5 px: the
    stored RPC is the bundle-adjusted one, the footprint was computed before)."""
    rpc = read_rpc(JAX_JSON)
    meta = json.loads(JAX_JSON.read_text())
    lonlat = np.array(meta["geojson"]["coordinates"][0])
    w, h = meta["width"], meta["height"]
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)

    def col_error(z):
        return float(np.asarray(rpc.project(np.array([*lonlat[0], z])))[0])

    z = brentq(col_error, -500.0, 500.0)
    xy = np.asarray(rpc.project(np.column_stack([lonlat, np.full(4, z)])))
    print(f"footprint height {z:.2f} m; residuals {xy - corners}")
    assert np.abs(xy[:, 0] - corners[:, 0]).max() < 0.02
    dy = xy[:, 1] - corners[:, 1]
    assert np.ptp(dy) < 0.02 and 1.0 < abs(dy.mean()) < 2.0


@pytest.mark.parametrize("style", [s.name for s in JSON_STYLES])
@pytest.mark.parametrize("nested", [False, True])
def test_json_spellings_round_trip_bits(tmp_path, real_data, style, nested):
    rpc = read_rpc(real_data / "formats" / "rpc_IKONOS.txt")
    style = next(s for s in JSON_STYLES if s.name == style)
    values = vendor_values(rpc)
    d = {}
    if style.first_index is not None:  # GDAL's metadata dict: each polynomial one string
        style = dataclasses.replace(style, first_index=None)
    for key, name, value in vendor_items(style, values):
        as_string = style.name == "rpc_txt" and key.field in COEFFS  # GDAL: one string
        d[name] = " ".join(map(repr, value)) if as_string else value
    path = tmp_path / "rpc.json"
    path.write_text(json.dumps({"img": "x.tif", "rpc": d} if nested else d))
    back = read_rpc(path)
    for f in ("num", "den", "ground_offset", "ground_scale", "image_offset", "image_scale"):
        assert np.array_equal(np.asarray(getattr(back, f)), np.asarray(getattr(rpc, f))), f


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda d: d["rpc"].update(row_scale=float("nan")),
            r"key rpc\.row_scale: nan is not a finite number",
        ),
        (lambda d: d["rpc"].update(alt_offset=True), r"key rpc\.alt_offset: expected a number"),
        (lambda d: d["rpc"].update(col_num=d["rpc"]["col_num"][:19]), r"col_num: 19 values"),
        (lambda d: d["rpc"].update(row_den=[1.0, "x"] + [0.0] * 18), r"row_den value 2: 'x'"),
        (lambda d: d["rpc"].pop("lat_scale"), r"missing key rpc\.lat_scale"),
        (lambda d: d.update(rpc=[1, 2]), r"key 'rpc' must hold the RPC object, got a list"),
    ],
)
def test_json_errors_name_file_and_key(tmp_path, edit, message):
    d = json.loads(JAX_JSON.read_text())
    edit(d)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(RPCFormatError, match=r"bad\.json: .*" + message):
        read_rpc(path)


def test_json_syntax_errors(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{"rpc": {"row_offset": 1,\n "row_offset": 2}}')
    with pytest.raises(RPCFormatError, match=r"bad\.json: .*'row_offset' appears twice"):
        read_rpc(path)
    path.write_text(JAX_JSON.read_text()[:900])
    with pytest.raises(RPCFormatError, match=r"bad\.json: line \d+: malformed JSON"):
        read_rpc(path)


# --------------------------------------------------------------------- zero denominators


@pytest.mark.parametrize("which, vendor", [("row_den", "line_den"), ("col_den", "samp_den")])
def test_all_zero_denominator_is_named_when_read(tmp_path, which, vendor):
    d = json.loads(JAX_JSON.read_text())
    d["rpc"][which] = [0.0] * 20
    path = tmp_path / "zero.json"
    path.write_text(json.dumps(d))
    with pytest.raises(RPCFormatError, match=rf"zero\.json: RPC denominator {vendor} .* all zero"):
        read_rpc(path)


# --------------------------------------------------------------------------- antimeridian

# GDAL autotest/alg/transformer.py::test_transformer_15 ("Test inverse RPC transform with DEM in
# [-180,180] but guessed longitude going beyond"): this RPC with LONG_OFF 179.9, then -179.9;
# GDAL localises pixel/line (0, 0), resp. (6600, 4400), at the DEM height 50 m to the points
# below, and its inverse transform of them, and of them written 360 degrees apart, returns the
# pixel within 0.1 (GDAL pixel = ours + 0.5).
GDAL_15 = dict(
    HEIGHT_OFF=50.0, HEIGHT_SCALE=10.0, LAT_OFF=0.0, LAT_SCALE=-0.105215174097221,
    LINE_OFF=2191.17012189569, LINE_SCALE=2197.23749680132, LONG_SCALE=0.124705315627701,
    SAMP_OFF=3300.0420831968, SAMP_SCALE=3295.90302088781,
    LINE_DEN_COEFF="1 0.000113241782375585 -7.43522609681362e-05 3.71535308900828e-08 0.000338102551252493 4.57912749279076e-07 -7.00823537484445e-08 9.01275640119332e-05 -0.000209723741981335 4.74972505083506e-09 7.2855438070338e-10 -3.16688523275456e-05 -4.49211037453489e-05 8.29706981496464e-12 7.58128162744879e-06 6.82536481272507e-07 2.58661007069147e-11 -3.9697791887986e-08 -5.06502821928986e-08 4.66978771069271e-11",  # noqa: E501
    LINE_NUM_COEFF="0.00673418095252569 -1.38985626744028 -0.645141238074041 1.4661564574111e-05 0.00022202101663831 -4.32910472926433e-06 -1.90048143949724e-06 -0.00374486341484218 -0.00041396053769863 1.14148334846788e-09 -1.20458144309064e-07 -0.00618122456017927 -0.00783023711720404 1.32704635552568e-09 -0.0032532225011433 -0.00355239507036451 6.20315160857432e-10 -4.75170167074672e-07 1.37652348819162e-07 9.53393990126859e-12",  # noqa: E501
    SAMP_DEN_COEFF="1 2.1759243891474e-05 -5.96367842636917e-06 6.03714873685079e-09 -0.000109764869260479 4.67786228725161e-07 -4.22013004308237e-07 0.000110379633112327 -0.00011679427405351 9.30515192365439e-09 1.09243100743555e-09 -3.29956656106618e-05 -4.1918167733603e-05 2.78076356769406e-11 -4.57011012884097e-06 -1.01453844685279e-05 2.60244039950836e-11 -3.52960090220746e-08 -4.49975439524006e-08 1.80641651820794e-11",  # noqa: E501
    SAMP_NUM_COEFF="-0.000776008179693209 -0.380692820465227 1.0647540743599 1.72660888229082e-06 0.0028311896140173 -1.0466632896253e-06 3.17728359468736e-06 -0.000150466834838251 0.000566231304705376 -7.34786296240808e-11 5.90340934437437e-07 -0.00169917056998316 -0.00231193494979752 -2.71280972480264e-09 0.00482224415396017 0.00596164573794891 7.58464598771136e-09 -1.46075167736497e-07 -4.64652272450397e-07 -5.59268858101854e-13",  # noqa: E501
)  # fmt: skip


@pytest.mark.parametrize(
    "lon_off, lonlat, gdal_pixel",
    [
        (179.9, (180.02280735469199, 0.061069145746997976), (0.0, 0.0)),
        (-179.9, (-180.02313813793387, -0.061398913932229765), (6600.0, 4400.0)),
    ],
)
def test_antimeridian_longitudes_360_apart_project_identically(
    tmp_path, lon_off, lonlat, gdal_pixel
):
    path = tmp_path / "am.json"  # GDAL's metadata names, as a JSON dictionary
    path.write_text(json.dumps({**GDAL_15, "LONG_OFF": lon_off}))
    rpc = read_rpc(path)
    lon, lat = lonlat
    other = lon - 360.0 if lon > 0 else lon + 360.0
    xy = np.asarray(rpc.project(np.array([[lon, lat, 50.0], [other, lat, 50.0]])))
    np.testing.assert_array_equal(xy[0], xy[1])
    np.testing.assert_allclose(xy[0] + 0.5, gdal_pixel, atol=0.1)
    # the validity test agrees as well
    assert bool(rpc.in_domain(np.array([other, lat, 50.0])))


def test_longitude_turns_far_from_the_antimeridian():
    """Away from +-180 deg, writing lon + 360 itself rounds the longitude (by up to 3e-14 deg,
    3 nm): equal to ~1e-8 px, not to the bit."""
    rpc = read_rpc(DIMAP_V1)
    g = np.array([[2.23, 31.0, 575.0], [2.23 + 360.0, 31.0, 575.0], [2.23 - 720.0, 31.0, 575.0]])
    xy = np.asarray(RPC.project(rpc, g))
    np.testing.assert_allclose(xy - xy[0], 0.0, rtol=0, atol=1e-7)
