"""Inputs by URL: images, model files and DEMs read from a local HTTP server with range requests
(started here, on 127.0.0.1) equal the same files read locally, and rasters are read by ranges,
never whole."""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest
import rasterio

from jaxgeo.cli import main
from jaxgeo.io import open_image, read_dem, read_rpc, write_geotiff_rpc, write_rpb
from jaxgeo.io._remote import RangeReader, RemotePath, as_path, is_remote


@pytest.fixture(scope="module")
def served(real_data, tmp_path_factory):
    """``(root folder, base URL, request log)`` of a local server of copies of real files
    (``range_server.py``, in a process of its own)."""
    root = tmp_path_factory.mktemp("served")
    for rel in ("ventoux/left_image.tif", "phr_ventoux__left_image.geom",
                "ventoux/dem/N44E005_srtm90.tif", "formats/rpc_PLEIADES.xml"):  # fmt: skip
        shutil.copy(real_data / rel, root / pathlib.Path(rel).name)
    demo = pathlib.Path(__file__).parents[2] / "jaxgeo" / "data" / "cartosat1_demo"
    shutil.copy(demo / "fore.txt", root / "fore_RPC.TXT")
    # a COG-like GeoTIFF with the RPC in its tags: the Ventoux crop with its product's model
    # moved to the crop's pixels
    image = open_image(real_data / "ventoux" / "left_image.tif",
                       model=real_data / "phr_ventoux__left_image.geom")  # fmt: skip
    with rasterio.open(real_data / "ventoux" / "left_image.tif") as src:
        pixels = src.read(1)
    write_geotiff_rpc(image.model.base_rpc(), root / "tagged.tif", pixels)
    # and a GeoTIFF without RPC tags whose RPC is an .RPB sidecar beside it
    with rasterio.open(root / "sidecar.tif", "w", driver="GTiff", width=500, height=500, count=1,
                       dtype=pixels.dtype) as dst:  # fmt: skip
        dst.write(pixels, 1)
    write_rpb(image.model.base_rpc(), root / "sidecar.RPB")
    log = tmp_path_factory.mktemp("server") / "requests.jsonl"
    env = {**os.environ, "no_proxy": "127.0.0.1,localhost", "NO_PROXY": "127.0.0.1,localhost"}
    script = pathlib.Path(__file__).with_name("range_server.py")
    server = subprocess.Popen([sys.executable, str(script), str(root), str(log)],
                              stdout=subprocess.PIPE, text=True, env=env)  # fmt: skip
    try:
        port = int(server.stdout.readline())
        yield root, f"http://127.0.0.1:{port}", _Log(log)
    finally:
        server.terminate()
        server.wait(timeout=10)


class _Log:
    """The server's requests so far: ``(method, path, range, body bytes)`` tuples."""

    def __init__(self, path: pathlib.Path):
        self.path = path

    def __iter__(self):
        if not self.path.exists():
            return iter(())
        return iter(tuple(json.loads(line)) for line in self.path.read_text().splitlines())

    def __repr__(self):
        return repr(list(self))


@pytest.fixture(autouse=True)
def _no_proxy(monkeypatch):
    """The local server is reached directly whatever proxy the environment names (urllib and
    GDAL's curl both honour ``no_proxy``)."""
    for var in ("no_proxy", "NO_PROXY"):
        monkeypatch.setenv(var, "127.0.0.1,localhost")


def _gets(log, name):
    return [entry for entry in log if entry[0] == "GET" and entry[1].split("?")[0] == f"/{name}"]


def test_remote_path_parts():
    url = "https://example.com/a%20b/scene/left_image.tif?X-Amz-Signature=ab//cd"
    p = as_path(url)
    assert isinstance(p, RemotePath) and is_remote(url) and str(p) == url  # no "//" folded
    assert (p.name, p.stem, p.suffix) == ("left_image.tif", "left_image", ".tif")
    assert str(p.with_suffix(".RPB")) == "https://example.com/a%20b/scene/left_image.RPB"
    assert str(p.parent) == "https://example.com/a%20b/scene"
    assert as_path("/vsis3/bucket/x.tif").stem == "x"
    assert not is_remote("scene/left_image.tif") and not is_remote(pathlib.Path("https:/x"))
    assert isinstance(as_path("left.tif"), pathlib.Path)


def test_image_and_model_by_url_equal_the_local_ones(served, real_data):
    root, base, log = served
    local = open_image(root / "left_image.tif", model=root / "phr_ventoux__left_image.geom")
    remote = open_image(f"{base}/left_image.tif?token=1",
                        model=f"{base}/phr_ventoux__left_image.geom")  # fmt: skip
    assert remote.name == "left_image" and remote.size == local.size == (500, 500)
    assert remote.origin == local.origin == (5000.0, 5000.0)  # the crop's frame, read by URL
    assert isinstance(remote.path, RemotePath) and str(remote.path).startswith("http://")
    xyh = np.array([[10.0, 20.0, 300.0], [480.0, 470.0, 1500.0]])
    g = np.asarray(local.model.localize(xyh[:, :2], xyh[:, 2]))
    assert np.array_equal(np.asarray(remote.model.project(g)), np.asarray(local.model.project(g)))
    # the GeoTIFF's RPC tag by range requests: bit-exact (GDAL's text would round it)
    tagged_local, tagged = open_image(root / "tagged.tif"), open_image(f"{base}/tagged.tif")
    assert np.array_equal(np.asarray(tagged.model.project(g)),
                          np.asarray(tagged_local.model.project(g)))  # fmt: skip
    assert np.array_equal(np.asarray(tagged.model.project(g)), np.asarray(local.model.project(g)))
    gets = _gets(log, "tagged.tif")
    assert gets and all(rng is not None for _, _, rng, _ in gets), gets
    assert sum(n for *_, n in gets) < (root / "tagged.tif").stat().st_size  # header, tag only


def test_rpc_sidecar_of_a_url_raster(served):
    """A raster by URL without RPC tags: its .RPB sidecar is asked for and read (as locally)."""
    root, base, log = served
    local, remote = open_image(root / "sidecar.tif"), open_image(f"{base}/sidecar.tif")
    g = np.array([[5.2, 44.2, 500.0], [5.21, 44.21, 900.0]])
    assert np.array_equal(np.asarray(remote.model.project(g)), np.asarray(local.model.project(g)))
    assert any(entry[1] == "/sidecar.RPB" and entry[3] > 0 for entry in log), log


@pytest.mark.parametrize("name", ["fore_RPC.TXT", "rpc_PLEIADES.xml"])
def test_text_model_files_by_url(served, name):
    root, base, _ = served
    local, remote = read_rpc(root / name), read_rpc(f"{base}/{name}")
    assert np.array_equal(np.asarray(local.num), np.asarray(remote.num))
    assert np.array_equal(np.asarray(local.den), np.asarray(remote.den))
    assert np.array_equal(np.asarray(local.image_offset), np.asarray(remote.image_offset))


def test_missing_url_is_named(served):
    _, base, _ = served
    with pytest.raises(FileNotFoundError, match="nothere.geom"):
        read_rpc(f"{base}/nothere.geom")
    with pytest.raises(Exception, match="nothere.tif"):
        open_image(f"{base}/nothere.tif")


def test_range_reader_reads_ranges_only(served):
    root, base, _ = served
    data = (root / "fore_RPC.TXT").read_bytes()
    f = RangeReader(f"{base}/fore_RPC.TXT")
    assert f.read(8) == data[:8] and f.seek(3000) == 3000 and f.read(9999) == data[3000:]
    with pytest.raises(OSError, match="by ranges"):
        f.read()
    with pytest.raises(OSError, match="does not answer range requests"):
        RangeReader(f"{base}/fore_RPC.TXT?noranges").read(8)


def test_dem_by_url_equals_the_local_one_read_by_ranges(served):
    root, base, log = served
    name = "N44E005_srtm90.tif"
    local, remote = read_dem(root / name), read_dem(f"{base}/{name}")
    assert remote.bounds_lonlat == local.bounds_lonlat and remote.shape == local.shape
    lonlat = np.array([[5.19, 44.20], [5.2013, 44.2071], [5.215, 44.22]])  # (one window)
    assert np.array_equal(np.asarray(remote.sample(lonlat)), np.asarray(local.sample(lonlat)))
    gets = _gets(log, name)
    assert gets and all(rng is not None for _, _, rng, _ in gets), gets
    assert sum(n for *_, n in gets) < 0.5 * (root / name).stat().st_size  # the tiles needed


def test_ortho_by_url_equals_the_local_run(served, tmp_path, real_data):
    root, base, log = served
    geoid = str(real_data / "ventoux" / "dem" / "egm96_15_crop_lon3-8_lat42-47.gtx")
    common = ["--geoid", geoid, "--crs", "EPSG:32631", "--res", "2",
              "--bounds", "675300", "4897180", "675500", "4897380", "--quiet"]  # fmt: skip
    local = ["ortho", str(root / "left_image.tif"), "--model",
             f"left_image={root / 'phr_ventoux__left_image.geom'}", "--dem",
             str(root / "N44E005_srtm90.tif"), "-o", str(tmp_path / "local.tif")]  # fmt: skip
    remote = ["ortho", f"{base}/left_image.tif", "--model",
              f"left_image={base}/phr_ventoux__left_image.geom", "--dem",
              f"{base}/N44E005_srtm90.tif", "-o", str(tmp_path / "remote.tif")]  # fmt: skip
    assert main(local + common) == 0
    assert main(remote + common) == 0
    with rasterio.open(tmp_path / "local.tif") as a, rasterio.open(tmp_path / "remote.tif") as b:
        assert a.transform == b.transform and a.crs == b.crs and a.shape == b.shape
        assert np.array_equal(a.read(), b.read()) and a.read_masks(1).any()  # data there
    gets = _gets(log, "left_image.tif")
    assert gets and all(rng is not None for _, _, rng, _ in gets), gets


def test_url_is_never_an_output(served, tmp_path, capsys):
    root, base, _ = served
    code = main(["ortho", str(root / "tagged.tif"), "--dem", str(root / "N44E005_srtm90.tif"),
                 "-o", f"{base}/out.tif", "--quiet"])  # fmt: skip
    assert code == 2
    assert "local file" in capsys.readouterr().err
    assert not (root / "out.tif").exists()


def test_adjusted_rpc_outputs_of_a_url_image(tmp_path):
    """The RPC files of an image by URL are named by its stem (no query string); a copy of the
    image (a download) is refused, naming the image."""
    from jaxgeo.io.internal import image_stem, plan_rpc_outputs

    url = "https://example.com/scene/left_image.tif?X-Amz-Signature=a//b"
    assert image_stem(url) == "left_image"
    plan = plan_rpc_outputs("left_image", url, tmp_path)
    assert plan.sidecar == tmp_path / "left_image_RPC.TXT" and plan.image_copy is None
    for option in ({"copy_image": True}, {"write_into": True}):
        with pytest.raises(ValueError, match="left_image.*read by URL"):
            plan_rpc_outputs("left_image", url, tmp_path, **option)
