"""RPC readers and writers against real vendor files, GDAL's own parsers and transformer.

GDAL reference: rasterio's RPCTransformer on an RPC that GDAL itself parsed from the vendor file
(the GeoTIFF tags; an ``_RPC.TXT``, DigitalGlobe ``.XML`` or DIMAP ``RPC_*.XML`` sidecar next to a
dummy image). GDAL's pixel/line = jaxgeo's + 0.5. The OSSIM ``.geom`` files, which GDAL does not
read, are checked against a minimal independent parse here, and the scene's ``.geom`` against the
scene's GeoTIFF as well.
"""

import os
import re
import shutil
import warnings

import numpy as np
import pytest
import rasterio
from rasterio.errors import NotGeoreferencedWarning
from rasterio.rpc import RPC as RasterioRPC
from rasterio.transform import RPCTransformer

from jaxgeo import RPC, read_rpc, write_geotiff_rpc, write_rpb, write_rpc_text
from jaxgeo.io import RPCFormatError, to_rasterio_rpc
from jaxgeo.io.internal import detect_rpc_format
from jaxgeo.models._rpc import B_TO_A

SCENE = "PHR1B_P_201709281038393_SEN_PRG_FC_178609-001"
SCENE_FILES = [f"{SCENE}.geom", f"RPC_{SCENE}.XML", f"{SCENE}.tif"]
REAL_FILES = {
    f"{SCENE}.geom": "ossim_geom",
    f"RPC_{SCENE}.XML": "dimap",
    f"{SCENE}.tif": "raster",
    "phr_ventoux__left_image.geom": "ossim_geom",
    "phr_ventoux__right_image.geom": "ossim_geom",
    "formats/rpc_IKONOS.txt": "rpc_txt",
    "formats/rpc_WV2.xml": "maxar_xml",
    "formats/rpc_PLEIADES.xml": "dimap",
}
REF_GROUND = np.array([7.048662660737769592, 43.72774839443545858, 0.0])
REF_IMAGE = np.array([100.0, 200.0])  # published (100.5, 200.5) in GDAL's convention, minus 0.5
FIELDS = ("num", "den", "ground_offset", "ground_scale", "image_offset", "image_scale")


def _quiet_open(path):
    warnings.simplefilter("ignore", NotGeoreferencedWarning)
    return rasterio.open(path)


def _dummy_tif(path):
    _write_tif(path, np.zeros((1, 8, 8), np.uint8))


def _write_tif(path, pixels):
    profile = dict(driver="GTiff", count=pixels.shape[0], height=pixels.shape[1],
                   width=pixels.shape[2], dtype=pixels.dtype)  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", **profile) as dst:
            dst.write(pixels)


def _geom_reference(path):
    """Independent minimal parse of an OSSIM .geom into a rasterio RPC (RPC00B files only)."""
    kv = dict(line.split(":", 1) for line in open(path).read().splitlines() if ":" in line)
    kv = {k.strip(): v.strip() for k, v in kv.items()}
    assert kv["polynomial_format"] == "B"
    scal = ["line_off", "samp_off", "lat_off", "long_off", "height_off", "line_scale"]
    scal += ["samp_scale", "lat_scale", "long_scale", "height_scale"]
    args = {k: float(kv[k]) for k in scal}
    for c in ("line_num", "line_den", "samp_num", "samp_den"):
        args[f"{c}_coeff"] = [float(kv[f"{c}_coeff_{i:02d}"]) for i in range(20)]
    return RasterioRPC(**args)


def gdal_rpc(real_data, name, tmp_path):
    """The RPC as GDAL parses it from the vendor file (see the module docstring)."""
    src_path = real_data / name
    if name.endswith(".tif"):
        image, sidecar = src_path, None
    elif name.endswith(".geom"):
        return _geom_reference(src_path)
    elif name.endswith("IKONOS.txt"):
        image, sidecar = tmp_path / "ik.tif", tmp_path / "ik_RPC.TXT"
    elif name.endswith("WV2.xml"):
        image, sidecar = tmp_path / "wv.tif", tmp_path / "wv.XML"
    else:  # DIMAP: GDAL pairs IMG_<base>_R1C1.tif with RPC_<base>.XML
        image, sidecar = tmp_path / "IMG_jaxgeo_ref_R1C1.tif", tmp_path / "RPC_jaxgeo_ref.XML"
    if sidecar is not None:
        _dummy_tif(image)
        shutil.copy(src_path, sidecar)
    with warnings.catch_warnings(), _quiet_open(image) as src:
        if sidecar is not None:
            assert sidecar.name in [os.path.basename(f) for f in src.files]
        return src.rpcs


def gdal_project(rpcs, ground):
    """GDAL's RPC transformer (ground -> pixel/line), returned in jaxgeo's convention."""
    with RPCTransformer(rpcs) as transformer:
        rows, cols = transformer.rowcol(ground[:, 0], ground[:, 1], zs=ground[:, 2], op=lambda v: v)
    return np.stack([np.asarray(cols, float), np.asarray(rows, float)], axis=-1) - 0.5


def cube_points(rpc, n=500, seed=0):
    low, high = np.asarray(rpc.validity_cube())
    return np.random.default_rng(seed).uniform(low, high, size=(n, 3))


def assert_same_rpc(a, b):
    for field in FIELDS:
        x, y = np.asarray(getattr(a, field)), np.asarray(getattr(b, field))
        assert np.array_equal(x, y), f"{field} differs: max {np.max(np.abs(x - y))}"


@pytest.fixture(scope="module")
def real_rpcs(real_data):
    return {name: read_rpc(real_data / name) for name in REAL_FILES}


# ------------------------------------------------------------------------------ reading


@pytest.mark.parametrize("name", REAL_FILES)
def test_reads_every_real_file(real_data, real_rpcs, name):
    assert detect_rpc_format(real_data / name) == REAL_FILES[name]
    rpc = real_rpcs[name]
    assert rpc.num.shape == (2, 20) and rpc.num.dtype == np.float64
    # the scene's own centre projects near the image centre (a sanity check of every field)
    centre = np.asarray(rpc.project(rpc.ground_offset))
    assert np.all(
        np.abs(centre - np.asarray(rpc.image_offset)) < 0.05 * np.asarray(rpc.image_scale)
    )


@pytest.mark.parametrize("name", SCENE_FILES)
def test_published_reference_point(real_data, real_rpcs, name):
    np.testing.assert_allclose(real_rpcs[name].project(REF_GROUND), REF_IMAGE, atol=1e-2)


@pytest.mark.parametrize("name", REAL_FILES)
def test_projection_equals_gdal(real_data, real_rpcs, tmp_path, name):
    rpc = real_rpcs[name]
    ground = cube_points(rpc)
    ours = np.asarray(rpc.project(ground))
    gdal = gdal_project(gdal_rpc(real_data, name, tmp_path), ground)
    err = np.max(np.abs(ours - gdal))
    assert err < 1e-6, f"{name}: max |jaxgeo - GDAL| = {err:.3g} px"


def test_scene_formats_agree_with_gdal_on_the_tif(real_data, real_rpcs, tmp_path):
    """geom, DIMAP XML and GeoTIFF of one scene: three parsers, one GDAL reference."""
    ground = cube_points(real_rpcs[SCENE_FILES[0]], seed=1)
    gdal = gdal_project(gdal_rpc(real_data, f"{SCENE}.tif", tmp_path), ground)
    for name in SCENE_FILES:
        assert np.max(np.abs(np.asarray(real_rpcs[name].project(ground)) - gdal)) < 1e-6, name


def test_geotiff_tag_is_read_exactly(real_data, real_rpcs):
    """The binary tag agrees with GDAL's 15-digit text of it, and is at least as precise."""
    with warnings.catch_warnings(), _quiet_open(real_data / f"{SCENE}.tif") as src:
        tags = src.tags(ns="RPC")
    rpc = real_rpcs[f"{SCENE}.tif"]
    assert float(tags["LINE_OFF"]) == float(f"{float(rpc.image_offset[1]):.15g}")
    np.testing.assert_allclose(
        rpc.num[1], [float(v) for v in tags["LINE_NUM_COEFF"].split()], rtol=1e-14
    )


@pytest.mark.parametrize("name", ["formats/rpc_PLEIADES.xml", f"RPC_{SCENE}.XML"])
def test_dimap_inverse_model_is_the_projection(real_data, real_rpcs, name):
    """DIMAP's Direct_Model (image -> ground) inverts what we read as ground -> image."""
    import xml.etree.ElementTree as ET

    direct = ET.parse(real_data / name).getroot().find(".//Direct_Model")
    coef = {e.tag: float(e.text) for e in direct}
    poly = {p: np.array([coef[f"{p}_{i}"] for i in range(1, 21)]) for p in
            ("SAMP_NUM_COEFF", "SAMP_DEN_COEFF", "LINE_NUM_COEFF", "LINE_DEN_COEFF")}  # fmt: skip
    rpc = real_rpcs[name]
    ground = cube_points(rpc, n=100)
    image = np.asarray(rpc.project(ground))
    from jaxgeo.models.internal import monomials

    h_norm = (ground[:, 2] - rpc.ground_offset[2]) / rpc.ground_scale[2]
    norm = np.column_stack([(image - rpc.image_offset) / rpc.image_scale, h_norm])
    m = np.asarray(monomials(norm))  # col in the L slot, row in the P slot (rpcm's convention)
    lon = rpc.ground_offset[0] + rpc.ground_scale[0] * (m @ poly["SAMP_NUM_COEFF"]) / (
        m @ poly["SAMP_DEN_COEFF"]
    )
    lat = rpc.ground_offset[1] + rpc.ground_scale[1] * (m @ poly["LINE_NUM_COEFF"]) / (
        m @ poly["LINE_DEN_COEFF"]
    )
    # 1e-6 deg is ~0.1 m ~ 0.2 px: far below what a swapped model or wrong slots would give
    assert np.max(np.abs(lon - ground[:, 0])) < 1e-6 and np.max(np.abs(lat - ground[:, 1])) < 1e-6


def test_format_comes_from_content_not_extension(real_data, real_rpcs, tmp_path):
    for name, fake in [("formats/rpc_IKONOS.txt", "a.xml"), ("formats/rpc_WV2.xml", "b_RPC.TXT"),
                       (f"{SCENE}.geom", "c.RPB"), (f"{SCENE}.tif", "d.txt")]:  # fmt: skip
        shutil.copy(real_data / name, tmp_path / fake)
        assert_same_rpc(read_rpc(tmp_path / fake), real_rpcs[name])


def test_nitf_rpc00b_tre(real_rpcs, tmp_path):
    """A NITF whose RPC lives in an RPC00B TRE (written by GDAL's NITF CreateCopy)."""
    from rasterio.shutil import copy as gdal_copy

    rpc = real_rpcs["formats/rpc_WV2.xml"]  # 7-digit values: exactly representable in RPC00B
    write_geotiff_rpc(rpc, tmp_path / "src.tif", np.zeros((16, 16), np.uint8))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        gdal_copy(tmp_path / "src.tif", tmp_path / "img.ntf", driver="NITF")
    for aux in tmp_path.glob("img.ntf.aux.xml"):
        aux.unlink()  # keep only the TRE as the RPC's source
    with _quiet_open(tmp_path / "img.ntf") as src:
        assert "RPC00B" in src.tags(ns="TRE")
    assert detect_rpc_format(tmp_path / "img.ntf") == "raster"
    assert_same_rpc(read_rpc(tmp_path / "img.ntf"), rpc)


def test_txt_variants_read_the_same(real_rpcs, tmp_path):
    rpc = real_rpcs["formats/rpc_IKONOS.txt"]
    write_rpc_text(rpc, tmp_path / "a_RPC.TXT")
    text = (tmp_path / "a_RPC.TXT").read_text()
    for poly in ("LINE_NUM_COEFF", "LINE_DEN_COEFF", "SAMP_NUM_COEFF", "SAMP_DEN_COEFF"):
        values = re.findall(rf"^{poly}_\d+: (\S+)$", text, re.M)
        text = re.sub(rf"^{poly}_\d+: \S+\n", "", text, flags=re.M)
        text += f"{poly}: {' '.join(values)}\n"  # GDAL metadata style: 20 values on one line
    text = "# comment\n" + text + "MAX_LAT: 0\nMAX_LAT: 1\n"  # unread repeats are fine
    (tmp_path / "b_RPC.TXT").write_text(text)
    assert_same_rpc(read_rpc(tmp_path / "b_RPC.TXT"), rpc)


# ----------------------------------------------------------- term orders and DIMAP variants


def _permute_geom_to_a(text):
    """OSSIM .geom text with every polynomial rewritten in RPC00A order."""
    out = text.replace("polynomial_format:  B", "polynomial_format:  A")
    for poly in ("line_num", "line_den", "samp_num", "samp_den"):
        keys = [f"{poly}_coeff_{i:02d}" for i in range(20)]
        b = [re.search(rf"^{k}:\s*(\S+)", text, re.M).group(1) for k in keys]
        for key, value in zip(keys, np.array(b)[B_TO_A], strict=True):
            out = re.sub(rf"^{key}:.*$", f"{key}:  {value}", out, flags=re.M)
    return out


def test_rpc00a_geom_equals_rpc00b_original(real_data, real_rpcs, tmp_path):
    name = "phr_ventoux__left_image.geom"
    text_a = _permute_geom_to_a((real_data / name).read_text())
    (tmp_path / "a.geom").write_text(text_a)
    (tmp_path / "a_as_b.geom").write_text(
        text_a.replace("polynomial_format:  A", "polynomial_format:  B")
    )
    original, rpc_a = real_rpcs[name], read_rpc(tmp_path / "a.geom")
    ground = cube_points(original)
    assert_same_rpc(rpc_a, original)
    np.testing.assert_array_equal(rpc_a.project(ground), original.project(ground))
    # negative control: the same coefficients taken in RPC00B order are far off
    wrong = np.asarray(read_rpc(tmp_path / "a_as_b.geom").project(ground))
    assert np.max(np.abs(wrong - np.asarray(original.project(ground)))) > 1.0


def test_rpc00a_rpb_and_maxar_xml_equal_rpc00b_original(real_data, real_rpcs, tmp_path):
    original = real_rpcs["formats/rpc_WV2.xml"]
    text = (real_data / "formats/rpc_WV2.xml").read_text()
    text = text.replace("<SPECID>RPC00B</SPECID>", "<SPECID>RPC00A</SPECID>")
    for tag in ("LINENUMCOEF", "LINEDENCOEF", "SAMPNUMCOEF", "SAMPDENCOEF"):
        body = re.search(rf"<{tag}>(.*?)</{tag}>", text, re.S).group(1)
        permuted = " ".join(np.array(body.split())[B_TO_A])
        text = text.replace(f"<{tag}>{body}</{tag}>", f"<{tag}>{permuted}</{tag}>")
    (tmp_path / "a.xml").write_text(text)
    assert_same_rpc(read_rpc(tmp_path / "a.xml"), original)

    write_rpb(original, tmp_path / "b.RPB")
    rpb = (tmp_path / "b.RPB").read_text().replace('"RPC00B"', '"RPC00A"')
    for name in ("lineNumCoef", "lineDenCoef", "sampNumCoef", "sampDenCoef"):
        body = re.search(rf"{name} = \((.*?)\);", rpb, re.S).group(1)
        values = [v.strip() for v in body.split(",")]
        rpb = rpb.replace(body, ",\n".join(np.array(values)[B_TO_A]))
    (tmp_path / "a.RPB").write_text(rpb)
    assert_same_rpc(read_rpc(tmp_path / "a.RPB"), original)


@pytest.mark.parametrize("variant", ["v3", "v3_first_col_0", "no_global_rfm"])
def test_dimap_variants(real_data, real_rpcs, tmp_path, variant):
    text = (real_data / f"RPC_{SCENE}.XML").read_text()
    if variant.startswith("v3"):  # Pleiades Neo names; FIRST_COL states the pixel origin
        text = text.replace("Inverse_Model>", "GroundtoImage_Values>")
        text = text.replace("Direct_Model>", "ImagetoGround_Values>")
        first = "1"
        if variant == "v3_first_col_0":
            first = "0"
            text = text.replace("<SAMP_OFF>20000.5<", "<SAMP_OFF>19999.5<")
            text = text.replace("<LINE_OFF>11470.5<", "<LINE_OFF>11469.5<")
        text = text.replace("<RFM_Validity>", "<RFM_Validity><ImagetoGround_Validity_Domain>"
                            f"<FIRST_ROW>{first}</FIRST_ROW><FIRST_COL>{first}</FIRST_COL>"
                            "</ImagetoGround_Validity_Domain>")  # fmt: skip
    else:
        text = text.replace("<Global_RFM>", "").replace("</Global_RFM>", "")
    (tmp_path / "v.XML").write_text(text)
    rpc = read_rpc(tmp_path / "v.XML")
    np.testing.assert_allclose(rpc.project(REF_GROUND), REF_IMAGE, atol=1e-2)
    assert_same_rpc(rpc, real_rpcs[f"RPC_{SCENE}.XML"])


# ------------------------------------------------------------------------------ writing

WRITERS = {
    "rpb": lambda rpc, p, **kw: write_rpb(rpc, p, **kw),
    "rpc_txt": lambda rpc, p, **kw: write_rpc_text(rpc, p, **kw),
    "rpc_txt_units": lambda rpc, p, **kw: write_rpc_text(rpc, p, units=True, **kw),
    "geotiff": lambda rpc, p, **kw: write_geotiff_rpc(rpc, p, **kw),
}
GDAL_NAMES = {"rpb": "img.RPB", "rpc_txt": "img_RPC.TXT", "rpc_txt_units": "img_RPC.TXT",
              "geotiff": "img.tif"}  # fmt: skip


def _awkward_rpc():
    """Values whose shortest decimal text is 17 digits long, to catch any rounding."""
    rng = np.random.default_rng(3)
    num, den = rng.normal(size=(2, 20)) / 3.0, rng.normal(size=(2, 20)) * 1e-7 / 3.0
    den[:, 0] = 1.0
    return RPC(num, den, [7.1 / 3, 43.7 / 3, 670.0 / 3], [0.1 / 3, 0.05 / 3, 630.0 / 7],
               [19999.5 / 3, 11469.5 / 7], [19999.5 / 7, 11469.5 / 3])  # fmt: skip


@pytest.mark.parametrize("writer", WRITERS)
def test_write_read_round_trip_is_bit_exact(real_rpcs, tmp_path, writer):
    for k, rpc in enumerate([*real_rpcs.values(), _awkward_rpc()]):
        path = tmp_path / f"{k}.{'tif' if writer == 'geotiff' else 'rpc'}"
        WRITERS[writer](rpc, path)
        assert_same_rpc(read_rpc(path), rpc)


@pytest.mark.parametrize("writer", WRITERS)
def test_gdal_reads_what_we_write(real_rpcs, tmp_path, writer):
    """GDAL parses our file itself (sidecar next to an image, or our GeoTIFF) and agrees."""
    rpc = real_rpcs["formats/rpc_WV2.xml"]
    target = tmp_path / GDAL_NAMES[writer]
    WRITERS[writer](rpc, target)
    if writer != "geotiff":
        _dummy_tif(tmp_path / "img.tif")
    with warnings.catch_warnings(), _quiet_open(tmp_path / "img.tif") as src:
        assert target.name in [os.path.basename(f) for f in src.files]
        rpcs = src.rpcs
    ground = cube_points(rpc, seed=2)
    assert np.max(np.abs(gdal_project(rpcs, ground) - np.asarray(rpc.project(ground)))) < 1e-6


@pytest.mark.parametrize("writer", WRITERS)
def test_writers_refuse_to_overwrite_and_leave_no_temp_files(real_rpcs, tmp_path, writer):
    first, second = real_rpcs["formats/rpc_WV2.xml"], real_rpcs["formats/rpc_IKONOS.txt"]
    path = tmp_path / "out.tif"
    WRITERS[writer](first, path)
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="out.tif"):
        WRITERS[writer](second, path)
    assert path.read_bytes() == before
    bad = RPC(np.full((2, 20), np.nan), second.den, second.ground_offset, second.ground_scale,
              second.image_offset, second.image_scale)  # fmt: skip
    with pytest.raises(ValueError, match="non-finite"):
        WRITERS[writer](bad, path, overwrite=True)
    assert path.read_bytes() == before
    WRITERS[writer](second, path, overwrite=True)
    assert_same_rpc(read_rpc(path), second)
    assert sorted(os.listdir(tmp_path)) == ["out.tif"]


def test_geotiff_placeholder_and_update_of_existing_image(real_rpcs, tmp_path):
    rpc, other = real_rpcs[f"{SCENE}.tif"], real_rpcs["formats/rpc_PLEIADES.xml"]
    write_geotiff_rpc(rpc, tmp_path / "placeholder.tif")
    with _quiet_open(tmp_path / "placeholder.tif") as src:
        assert (src.height, src.width) == (22940, 40000)  # the scene's size, from the RPC
    assert os.path.getsize(tmp_path / "placeholder.tif") < 2_000_000  # sparse: no pixel data

    image = tmp_path / "image.tif"
    pixels = np.arange(3 * 40 * 50, dtype=np.uint16).reshape(3, 40, 50)
    _write_tif(image, pixels)
    with pytest.raises(FileExistsError, match="image.tif"):
        write_geotiff_rpc(rpc, image)  # a new file would replace the image: refused
    write_geotiff_rpc(rpc, image, update=True)
    assert_same_rpc(read_rpc(image), rpc)
    with pytest.raises(FileExistsError, match="already holds RPC"):
        write_geotiff_rpc(other, image, update=True)
    write_geotiff_rpc(other, image, update=True, overwrite=True)
    assert_same_rpc(read_rpc(image), other)
    with _quiet_open(image) as src:
        np.testing.assert_array_equal(src.read(), pixels)
    assert sorted(os.listdir(tmp_path)) == ["image.tif", "placeholder.tif"]


def test_rasterio_rpc_conversion_is_exact(real_rpcs):
    rpc = _awkward_rpc()
    from jaxgeo.io import from_rasterio_rpc

    assert_same_rpc(from_rasterio_rpc(to_rasterio_rpc(rpc)), rpc)


# ------------------------------------------------------------------------------ bad input


def _edit(real_data, tmp_path, name, edit, out="bad.rpc"):
    text = (real_data / name).read_text()
    new = edit(text)
    assert new != text
    (tmp_path / out).write_text(new)
    return tmp_path / out


def test_missing_path(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere_RPC.TXT"):
        read_rpc(tmp_path / "nowhere_RPC.TXT")


def test_unknown_formats(tmp_path):
    (tmp_path / "notes.txt").write_text("hello\nworld\n")
    (tmp_path / "other.xml").write_text("<doc><a>1</a></doc>")
    (tmp_path / "noise.bin").write_bytes(bytes(range(256)) * 4)
    for name, message in [("notes.txt", "not a recognised RPC file"), ("other.xml", "neither"),
                          ("noise.bin", "not a readable raster")]:  # fmt: skip
        with pytest.raises(RPCFormatError, match=rf"{name}.*{message}"):
            read_rpc(tmp_path / name)
    image = tmp_path / "plain.tif"
    _dummy_tif(image)
    with pytest.raises(RPCFormatError, match=r"plain\.tif.*no RPC"):
        read_rpc(image)


@pytest.mark.parametrize(
    ("name", "cut", "message"),
    [
        ("formats/rpc_IKONOS.txt", 40, r"missing key LINE_DEN_COEFF_11"),
        (f"{SCENE}.geom", 60, r"missing key line_off"),
        ("formats/rpc_WV2.xml", 200, r"malformed XML.*line"),
        (f"RPC_{SCENE}.XML", 120, r"malformed XML.*line"),
    ],
)
def test_truncated_text_files(real_data, tmp_path, name, cut, message):
    """Files cut after ``cut`` lines (at a line end: a cut mid-number can look complete)."""
    path = _edit(real_data, tmp_path, name, lambda t: "\n".join(t.splitlines()[:cut]) + "\n")
    with pytest.raises(RPCFormatError, match=rf"bad\.rpc.*{message}"):
        read_rpc(path)


def test_truncated_rpb_and_geotiff(real_rpcs, tmp_path):
    write_rpb(real_rpcs["formats/rpc_WV2.xml"], tmp_path / "full.RPB")
    text = (tmp_path / "full.RPB").read_text()
    (tmp_path / "cut.RPB").write_text(text[: text.index("sampNumCoef") + 200])
    with pytest.raises(RPCFormatError, match=r"cut\.RPB: line \d+: list sampNumCoef is not closed"):
        read_rpc(tmp_path / "cut.RPB")
    write_geotiff_rpc(real_rpcs["formats/rpc_WV2.xml"], tmp_path / "full.tif", shape=(64, 64))
    (tmp_path / "cut.tif").write_bytes((tmp_path / "full.tif").read_bytes()[:300])
    with pytest.raises(RPCFormatError, match=r"cut\.tif: RPCCoefficientTag .* cut off"):
        read_rpc(tmp_path / "cut.tif")


MISSING_KEY_CASES = [
    ("formats/rpc_IKONOS.txt", r"SAMP_SCALE:.*\n", "missing key SAMP_SCALE"),
    (f"{SCENE}.geom", r"long_scale:.*\n", "missing key long_scale"),
    (f"RPC_{SCENE}.XML", r"<HEIGHT_OFF>670</HEIGHT_OFF>", "missing <HEIGHT_OFF>"),
    ("formats/rpc_WV2.xml", r"<LATSCALE>.*</LATSCALE>", "missing <LATSCALE>"),
    (f"RPC_{SCENE}.XML", r"(?s)\s*<Inverse_Model>.*</Inverse_Model>", "only a <Direct_Model>"),
]


@pytest.mark.parametrize(("name", "pattern", "message"), MISSING_KEY_CASES)
def test_missing_key(real_data, tmp_path, name, pattern, message):
    path = _edit(real_data, tmp_path, name, lambda t: re.sub(pattern, "", t))
    with pytest.raises(RPCFormatError, match=rf"bad\.rpc.*{re.escape(message)}"):
        read_rpc(path)


def test_missing_coefficient_in_xml_and_rpb(real_data, real_rpcs, tmp_path):
    def drop_last_line_den_7(text):  # the Inverse_Model's, which follows the Direct_Model's
        start = text.rindex("<LINE_DEN_COEFF_7>")
        return text[:start] + text[text.index("\n", start) :]

    path = _edit(real_data, tmp_path, f"RPC_{SCENE}.XML", drop_last_line_den_7)
    with pytest.raises(RPCFormatError, match=r"bad\.rpc: missing <LINE_DEN_COEFF_7>"):
        read_rpc(path)
    write_rpb(real_rpcs["formats/rpc_WV2.xml"], tmp_path / "a.RPB")
    text = re.sub(r"\tlatScale = .*;\n", "", (tmp_path / "a.RPB").read_text())
    (tmp_path / "b.RPB").write_text(text)
    with pytest.raises(RPCFormatError, match=r"b\.RPB: missing key latScale"):
        read_rpc(tmp_path / "b.RPB")
    text = re.sub(
        r"(sampDenCoef = \(\n\s*\S+,)", r"\1\n\t\t\t1.0,", (tmp_path / "a.RPB").read_text()
    )
    (tmp_path / "c.RPB").write_text(text)
    with pytest.raises(
        RPCFormatError, match=r"c\.RPB: line \d+ \(sampDenCoef\): 21 values, expected 20"
    ):
        read_rpc(tmp_path / "c.RPB")


IK, GEOM, DIMAP, WV2 = (
    "formats/rpc_IKONOS.txt",
    f"{SCENE}.geom",
    f"RPC_{SCENE}.XML",
    "formats/rpc_WV2.xml",
)
BAD_VALUE_CASES = [  # (file, text to replace (None: append), replacement, expected message)
    (IK, "LINE_NUM_COEFF_5: -2.314111221699151E-03", "LINE_NUM_COEFF_5: abc",
     "line 15 (LINE_NUM_COEFF_5): 'abc' is not a number"),
    (IK, "LAT_OFF: -34.90300000", "LAT_OFF: nan", "line 3 (LAT_OFF): 'nan' is not a number"),
    (GEOM, "samp_off:  19999.5", "samp_off:  19999,5", "(samp_off): '19999,5' is not a number"),
    (DIMAP, "<SAMP_SCALE>19999.5<", "<SAMP_SCALE>20k<", "<SAMP_SCALE>: '20k' is not a number"),
    (WV2, "<SAMPNUMCOEF>1.188955000000000e-05 ", "<SAMPNUMCOEF>1.18895e-05x ",
     "<SAMPNUMCOEF> value 1: '1.18895e-05x' is not a number"),
    (IK, "LINE_SCALE: +005124.00", "LINE_SCALE: 0", "image_scale holds a zero scale"),
    (IK, None, "LINE_OFF: 1.0\n", "key LINE_OFF repeats line 1"),
    (IK, None, "LINE_NUM_COEFF_21: 1.0\n", "index out of range"),
    (GEOM, "adj_param_0.parameter:  0", "adj_param_0.parameter: 2", "non-zero OSSIM adjustment"),
]  # fmt: skip


@pytest.mark.parametrize(("name", "old", "new", "message"), BAD_VALUE_CASES)
def test_bad_values(real_data, tmp_path, name, old, new, message):
    path = _edit(
        real_data, tmp_path, name, lambda t: t + new if old is None else t.replace(old, new)
    )
    with pytest.raises(RPCFormatError, match=rf"bad\.rpc.*{re.escape(message)}"):
        read_rpc(path)
