"""The vendor's stated accuracy beside an RPC (RPC00B ERR_BIAS / ERR_RAND, m): read from every
format that carries it (issue 53, item 5), unknown where a format has none or says -1 / 0."""

import json
import pathlib

import numpy as np
import pytest

from jaxgeo.io import (
    RPCAccuracy,
    RPCFormatError,
    open_image,
    read_rpc,
    read_rpc_accuracy,
    write_geotiff_rpc,
    write_ossim_geom,
    write_rpb,
    write_rpc_text,
)

REAL = pathlib.Path(__file__).resolve().parents[1] / "data" / "real"


@pytest.mark.parametrize(
    "name, bias_m, rand_m",
    [
        ("formats/rpc_IKONOS.txt", 3.31, 0.5),  # "ERR_BIAS: 0003.31 meters"
        ("formats/rpc_WV2.xml", 26.68, 0.14),  # Maxar <ERRBIAS>, <ERRRAND>
        ("formats/rpc_PLEIADES.xml", None, None),  # DIMAP: only the RFM's fit errors
        ("RPC_PHR1B_P_201709281038393_SEN_PRG_FC_178609-001.XML", None, None),
        ("phr_ventoux__left_image.geom", None, None),  # OTB's "bias_error: 0": unknown
    ],
)
def test_real_files(name, bias_m, rand_m):
    acc = read_rpc_accuracy(REAL / name)
    assert (acc.bias_m, acc.rand_m) == (bias_m, rand_m)
    assert acc.known == (bias_m is not None)
    if bias_m is not None:
        assert acc.horizontal_m == pytest.approx(np.hypot(bias_m, rand_m))
        assert acc.describe() == f"vendor ERR_BIAS {bias_m:g} m, ERR_RAND {rand_m:g} m"
    else:
        assert acc.horizontal_m is None and acc.describe() == "unknown"


@pytest.fixture(scope="module")
def rpc():
    return read_rpc(REAL / "formats" / "rpc_IKONOS.txt")


def test_every_writable_format_carries_the_values(rpc, tmp_path):
    """Synthetic files of each format with stated values (and jaxgeo's own, which say -1)."""
    txt = write_rpc_text(rpc, tmp_path / "a_RPC.TXT")
    assert not read_rpc_accuracy(txt).known  # jaxgeo writes -1: an adjusted model's are unknown
    text = txt.read_text().replace("ERR_BIAS: -1", "ERR_BIAS: 2.5 meters")
    (tmp_path / "b_RPC.TXT").write_text(text.replace("ERR_RAND: -1", "ERR_RAND: 0.25"))
    assert read_rpc_accuracy(tmp_path / "b_RPC.TXT") == RPCAccuracy(
        2.5, 0.25, str(tmp_path / "b_RPC.TXT")
    )

    rpb = write_rpb(rpc, tmp_path / "c.RPB")
    assert not read_rpc_accuracy(rpb).known
    (tmp_path / "d.RPB").write_text(rpb.read_text().replace("errBias = -1;", "errBias = 4.0;"))
    acc = read_rpc_accuracy(tmp_path / "d.RPB")
    assert (acc.bias_m, acc.rand_m) == (4.0, None)

    geom = write_ossim_geom(rpc, tmp_path / "e.geom")  # "bias_error: 0": unknown
    assert not read_rpc_accuracy(geom).known
    (tmp_path / "f.geom").write_text(geom.read_text().replace("bias_error: 0", "bias_error: 1.5"))
    assert read_rpc_accuracy(tmp_path / "f.geom").bias_m == 1.5

    from jaxgeo.io import to_rasterio_rpc

    values = to_rasterio_rpc(rpc).to_dict() | {"err_bias": 6.0, "err_rand": -1.0}
    (tmp_path / "g.json").write_text(json.dumps(values))  # rasterio's names
    (tmp_path / "h.json").write_text(json.dumps({k.upper(): v for k, v in values.items()}))
    for name in ("g.json", "h.json"):  # and GDAL's (s2p's dumps of the tag)
        acc = read_rpc_accuracy(tmp_path / name)
        assert (acc.bias_m, acc.rand_m) == (6.0, None)
    # every reader still gives the same RPC
    for name in ("b_RPC.TXT", "d.RPB", "f.geom", "g.json", "h.json"):
        np.testing.assert_array_equal(read_rpc(tmp_path / name).num, rpc.num)


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")
def test_geotiff_tag_and_gdal_metadata(rpc, tmp_path):
    """The RPCCoefficientTag's first two doubles, and GDAL's metadata of other rasters."""
    import rasterio
    from rasterio.rpc import RPC as RasterioRPC

    from jaxgeo.io import to_rasterio_rpc

    plain = write_geotiff_rpc(rpc, tmp_path / "plain.tif", shape=(64, 64))
    assert not read_rpc_accuracy(plain).known
    theirs = to_rasterio_rpc(rpc).to_dict()
    theirs.update(err_bias=3.0, err_rand=0.5)
    profile = dict(driver="GTiff", width=8, height=8, count=1, dtype="uint8")
    with rasterio.open(tmp_path / "tag.tif", "w", rpcs=RasterioRPC(**theirs), **profile):
        pass
    acc = read_rpc_accuracy(tmp_path / "tag.tif")
    assert (acc.bias_m, acc.rand_m) == (3.0, 0.5)
    # a raster whose RPC GDAL reads from a sidecar (no tag): rasterio's err_bias / err_rand
    with rasterio.open(tmp_path / "side.tif", "w", **profile):
        pass
    text = write_rpb(rpc, tmp_path / "side.RPB").read_text()
    (tmp_path / "side.RPB").write_text(text.replace("errBias = -1;", "errBias = 7.5;"))
    acc = read_rpc_accuracy(tmp_path / "side.tif")
    assert (acc.bias_m, acc.rand_m) == (7.5, None)
    # the image carries them beside its model
    image = open_image(tmp_path / "tag.tif")
    assert image.vendor_accuracy.bias_m == 3.0
    assert open_image(tmp_path / "tag.tif", model=plain).vendor_accuracy.known is False


def test_bad_values_are_named(rpc, tmp_path):
    text = write_rpc_text(rpc, tmp_path / "a_RPC.TXT").read_text()
    (tmp_path / "bad_RPC.TXT").write_text(text.replace("ERR_BIAS: -1", "ERR_BIAS: n/a"))
    with pytest.raises(RPCFormatError, match=r"bad_RPC.TXT: line 1 \(ERR_BIAS\)"):
        read_rpc(tmp_path / "bad_RPC.TXT")
    (tmp_path / "twice_RPC.TXT").write_text(text + "ERR_BIAS: 3\n")
    with pytest.raises(RPCFormatError, match="twice_RPC.TXT: line .*ERR_BIAS repeats line 1"):
        read_rpc_accuracy(tmp_path / "twice_RPC.TXT")
    (tmp_path / "empty_RPC.TXT").write_text(text.replace("ERR_BIAS: -1", "ERR_BIAS:"))
    assert read_rpc_accuracy(tmp_path / "empty_RPC.TXT").bias_m is None
