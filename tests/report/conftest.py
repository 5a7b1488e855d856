"""Pages to check, made once per session: an adjustment of the embedded demo block (the library
call ``jaxgeo adjust`` makes) and, from small synthetic rasters (no matching: fast), a DSM, an
ortho image and a co-registration."""

import html.parser
import io
import shutil

import numpy as np
import pytest
import rasterio
from affine import Affine

X0, Y0, CELL_M, N = 700_000.0, 4_800_000.0, 1.0, 160
CRS = "EPSG:32631"


def hills(east_m, north_m):
    """Smooth hills and a tilt on the grid (a function of map coordinates: shifted copies are
    exact)."""
    u, v = east_m - X0, north_m - Y0
    z = 150.0 + 0.05 * u - 0.03 * v
    rng = np.random.default_rng(11)
    for _ in range(12):
        cx, cy, s, h = (
            rng.uniform(0, N),
            -rng.uniform(0, N),
            rng.uniform(8, 30),
            rng.uniform(-8, 15),
        )
        z += h * np.exp(-((u - cx) ** 2 + (v - cy) ** 2) / (2 * s * s))
    return z


def centres():
    cols, rows = np.meshgrid(np.arange(N), np.arange(N))
    return X0 + (cols + 0.5) * CELL_M, Y0 - (rows + 0.5) * CELL_M


def write_bands(path, bands, names=None, dtype="float32", nodata=np.nan):
    bands = np.asarray(bands)
    profile = dict(driver="GTiff", width=bands.shape[2], height=bands.shape[1],
                   count=bands.shape[0], dtype=dtype, crs=CRS, nodata=nodata,
                   transform=Affine(CELL_M, 0, X0, 0, -CELL_M, Y0))  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(bands.astype(dtype))
        for k, name in enumerate(names or ()):
            dst.set_band_description(k + 1, name)
    return path


def synthetic_dsm(path):
    """A jaxgeo-like DSM: height, count, spread, filled, height_sigma; a hole without heights,
    a small interpolated patch."""
    e, n = centres()
    z = hills(e, n)
    count = np.full(z.shape, 3.0)
    filled = np.zeros(z.shape)
    z[20:40, 30:60] = np.nan  # no height
    filled[100:104, 100:110], count[100:104, 100:110] = 1.0, 0.0
    sigma = 0.5 + 0.01 * (e - X0)
    sigma[np.isnan(z)] = np.nan
    names = ("height", "count", "spread", "filled", "height_sigma")
    return write_bands(path, [z, count, np.full(z.shape, 0.2), filled, sigma], names)


@pytest.fixture(scope="session")
def pages(tmp_path_factory):
    """Page name -> the HTML report written for it (``adjust``, ``dsm``, ``ortho``, ``coreg``)."""
    from jaxgeo.bundle import adjust_files
    from jaxgeo.coreg import coregister
    from jaxgeo.report import (
        write_adjustment_report,
        write_coregistration_report,
        write_dsm_report,
        write_ortho_report,
    )
    from jaxgeo.simulate import demo_dir

    w = tmp_path_factory.mktemp("pages")
    demo = w / "demo"
    shutil.copytree(demo_dir(), demo)
    run = adjust_files({"fore": demo / "fore.txt", "aft": demo / "aft.txt"},
                       demo / "observations.csv", demo / "ground.csv", bias="shift")  # fmt: skip
    out = {"adjust": write_adjustment_report(run, w / "adjust.report.html")}
    out["dsm"] = write_dsm_report(synthetic_dsm(w / "dsm.tif"), w / "dsm.report.html")
    e, n = centres()
    rgb = [np.sin(e / 7.0) + np.cos(n / 5.0) + k for k in range(3)]
    rgb = np.clip(40 * (np.asarray(rgb) + 3), 0, 255)
    rgb[:, :10, :] = 0  # no data
    write_bands(w / "ortho.tif", rgb, dtype="uint8", nodata=0)
    out["ortho"] = write_ortho_report(w / "ortho.tif", w / "ortho.report.html")
    write_bands(w / "ref.tif", [hills(e, n)])
    write_bands(w / "moved.tif", [hills(e - 2.0, n + 1.0) + 0.5])
    result = coregister(w / "moved.tif", w / "ref.tif", w / "aligned.tif", diff=w / "dh.tif")
    out["coreg"] = write_coregistration_report(result, w / "moved.tif", w / "ref.tif",
                                               w / "aligned.report.html")  # fmt: skip
    return out


class Sections(html.parser.HTMLParser):
    """The ``<h2>`` sections of a page with the ``src`` of their images, and what a
    self-contained page must not hold (scripts, links, remote sources)."""

    def __init__(self):
        super().__init__()
        self.sections: dict[str, list[str]] = {}
        self.current, self.heading = None, False
        self.forbidden: list[str] = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "h2":
            self.heading = True
        elif tag == "img":
            self.sections.setdefault(self.current, []).append(attrs.get("src", ""))
        if tag in ("script", "link", "iframe") or any(
            str(v).startswith(("http:", "https:", "//")) for v in attrs.values()
        ):
            self.forbidden.append(tag)

    def handle_data(self, data):
        if self.heading:
            self.current = data.strip()
            self.sections.setdefault(self.current, [])
            self.heading = False


def sections(path) -> Sections:
    parser = Sections()
    parser.feed(path.read_text(encoding="utf-8"))
    return parser


def png_size(src: str) -> tuple[int, int]:
    """(width, height) of a ``data:image/png;base64`` image, decoded (fails on a bad PNG)."""
    import base64

    from PIL import Image

    prefix = "data:image/png;base64,"
    assert src.startswith(prefix), src[:40]
    image = Image.open(io.BytesIO(base64.b64decode(src[len(prefix) :], validate=True)))
    image.load()
    assert image.format == "PNG"
    return image.size
