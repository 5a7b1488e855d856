"""One grid per job: target-aligned pixels (edges on multiples of the resolution), a common
default resolution for the views of one scene, and ``like`` (another raster's grid, exactly), for
orthoimages and DSMs.

Two simulated views of one painted ground (the Pleiades Nice RPC, the second view through an
affine bias: another crop and a 6 % finer GSD) at default settings fall on one grid; with
``like`` they share transform and shape, and where both have data each pixel shows the same
ground (about 25 s on a busy 2-core machine: two renderings and three orthoimages, the one
end-to-end check that a common grid puts the same ground under the same pixel). Real data: the
two Ventoux Pleiades crops through the command line."""

import math
import shutil

import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine
from scipy.ndimage import binary_erosion

import jaxgeo
from jaxgeo.cli import main
from jaxgeo.io import open_image, read_dem
from jaxgeo.models import AffineBias, Biased
from jaxgeo.ortho import OrthoError, OrthoSettings, common_resolution, orthorectify, plan_ortho
from jaxgeo.ortho._grid import on_dem
from jaxgeo.stereo import DSMSettings, DSMSettingsError, StereoError, plan_dsm
from jaxgeo.tiles import OutputGrid, TileSettings
from tests.conftest import PLEIADES_TIF

WAVELENGTH_M = 12.0


def _write(path, crs, transform, width=8, height=6, count=1):
    with rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=count,
                       dtype="float32", crs=crs, transform=transform) as dst:  # fmt: skip
        dst.write(np.zeros((count, height, width), "float32"))
    return path


@pytest.mark.parametrize("res", [0.5, 0.3, 1.1, 2.5, 4.5e-6])
def test_tap_edges_are_multiples_of_the_resolution(res):
    rng = np.random.default_rng(7)
    for _ in range(50):
        w, s = rng.uniform(-5e5, 5e5, 2) * (res / 0.5)
        e, n = w + rng.uniform(1, 400) * res, s + rng.uniform(1, 400) * res
        g = OutputGrid.covering((w, s, e, n), "EPSG:32631", res)
        gw, gs, ge, gn = g.bounds
        for v in (gw, gs, ge, gn):  # every edge a multiple of res
            assert abs(v / res - round(v / res)) < 1e-6, (v, res)
        # the smallest such grid holding the bounds
        tol = 1e-6 * res
        assert gw <= w + tol and ge >= e - tol and gs <= s + tol and gn >= n - tol
        assert w - gw < res and n - gn > -res and ge - e < res + tol and s - gs < res + tol
        # without tap: from (W, N) exactly, reaching E and S
        f = OutputGrid.covering((w, s, e, n), "EPSG:32631", res, tap=False)
        fw, fs, fe, _ = f.bounds
        assert (f.west, f.north) == (w, n) and fe >= e - tol and fs <= s + tol
        assert fe - e < res and s - fs < res
    # an edge already on a multiple stays there (3.3 / 1.1 is 2.9999999999999996)
    g = OutputGrid.covering((3.3, 0.0, 6.6, 3.3), "EPSG:32631", 1.1)
    assert (g.width, g.height, g.west) == (3, 3, 3.3)


def test_the_default_resolution_is_the_gsd_rounded_to_a_common_value():
    assert {common_resolution(g) for g in (0.497, 0.532, 0.521)} == {0.5}  # the s2p triplet
    rounded = [common_resolution(g) for g in (0.31, 0.56, 0.7, 2.2, 4.6e-6)]
    assert rounded == [0.3, 0.6, 0.8, 2.0, 5e-6]
    for gsd in np.geomspace(0.05, 50, 400):
        r = common_resolution(gsd)
        assert abs(r / gsd - 1) < 0.16 and common_resolution(r) == r
    with pytest.raises(ValueError, match="positive"):
        common_resolution(0.0)


def test_like_takes_a_rasters_grid_and_refuses_one_without(tmp_path, real_data):
    t = Affine(0.5, 0, 698000.0, 0, -0.5, 4793000.0)
    path = _write(tmp_path / "a.tif", "EPSG:32631", t, 8, 6)
    g = OutputGrid.of_raster(path)
    assert g.transform == t and (g.width, g.height) == (8, 6) and g.crs.to_epsg() == 32631
    assert g.bounds == (698000.0, 4792997.0, 698004.0, 4793000.0) and g.source == str(path)
    assert g == OutputGrid(pyproj.CRS.from_epsg(32631), 0.5, 698000.0, 4793000.0, 8, 6)
    odd = OutputGrid.of_raster(_write(tmp_path / "b.tif", "EPSG:4326",
                                      Affine(1e-4, 0, 5.1, 0, -2e-4, 44.3)))  # fmt: skip
    assert odd.transform == Affine(1e-4, 0, 5.1, 0, -2e-4, 44.3)
    refused = {
        "no CRS": (real_data / "ventoux" / "left_image.tif", "has no CRS"),
        "rotated": (_write(tmp_path / "r.tif", "EPSG:32631", Affine(0.5, 0.1, 0, 0.1, -0.5, 0)),
                    "rotated"),
        "south-up": (_write(tmp_path / "s.tif", "EPSG:32631", Affine(0.5, 0, 0, 0, 0.5, 0)),
                     "north-up"),
        "missing": (tmp_path / "none.tif", "no such file"),
        "not a raster": (tmp_path / "t.txt", "not a raster"),
    }  # fmt: skip
    (tmp_path / "t.txt").write_text("hello")
    for case, (p, message) in refused.items():
        with pytest.raises(OrthoError, match=message) as err:
            OrthoSettings(like=p)
        assert str(p) in str(err.value) and str(err.value).startswith("like: "), case
    # the options of a grid are refused with it, each named
    for given, named in (({"res_m": 0.5}, "res_m"), ({"crs": 32631}, "crs"),
                         ({"crs": 32631, "bounds": (0, 0, 1, 1)}, "crs, bounds"),
                         ({"tap": False}, "tap=False")):  # fmt: skip
        with pytest.raises(OrthoError, match=f"{named} cannot be given with it"):
            OrthoSettings(like=path, **given)
    assert OrthoSettings(like=path).like == g and OrthoSettings(like=g) == OrthoSettings(like=path)
    # a DSM takes a projected grid in metres with square cells, and its res_m and epsg
    s = DSMSettings(like=path)
    assert (s.res_m, s.epsg, s.like) == (0.5, 32631, g)
    with pytest.raises(DSMSettingsError, match="not a projected CRS"):
        DSMSettings(like=odd)
    with pytest.raises(DSMSettingsError, match="square"):
        DSMSettings(like=_write(tmp_path / "n.tif", "EPSG:32631", Affine(1, 0, 0, 0, -2, 0)))
    with pytest.raises(DSMSettingsError, match="res_m 1 cannot be given"):
        DSMSettings(like=path, res_m=1.0)
    with pytest.raises(DSMSettingsError, match="epsg 32632 cannot be given"):
        DSMSettings(like=path, epsg=32632)


def _pattern(e, n):
    return np.sin(2 * np.pi * e / WAVELENGTH_M) * np.cos(2 * np.pi * n / WAVELENGTH_M)


def _render(model, dem, path, size=96):
    """An image of ``size`` px a side through ``model``: band 1 the ground pattern, bands 2-3
    the UTM 32N easting and northing (minus 350 km, 4840 km) each pixel sees on the DEM."""
    col, row = np.meshgrid(np.arange(size, dtype=float), np.arange(size, dtype=float))
    xy = np.stack([col, row], -1).reshape(-1, 2)
    lon0, lat0 = (float(v) for v in model.localize(np.array([size / 2, size / 2]), 200.0)[:2])
    grid = dem.grid((lon0 - 0.01, lat0 - 0.01, lon0 + 0.01, lat0 + 0.01))
    # (smooth hills, no terrain hidden: the line of sight meets the DEM once; on_dem is the
    # program the orthoimage's footprint compiles anyway)
    g, ok = on_dem(model, xy, grid)
    assert ok.all()
    e, n = pyproj.Transformer.from_crs(4326, 32632, always_xy=True).transform(g[:, 0], g[:, 1])
    bands = np.stack([_pattern(e, n), e - 350_000.0, n - 4_840_000.0]).reshape(3, size, size)
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=3,
                       dtype="float64") as dst:  # fmt: skip
        dst.write(bands)
    return path


def test_two_views_of_one_ground_share_a_grid(tmp_path, real_data, nice_dem_synthetic):
    import cv2

    rpc = Biased(jaxgeo.read_rpc(real_data / PLEIADES_TIF), AffineBias())  # one model type,
    # the second view: another crop (-31.4, 17.7 px) and a GSD 6 % finer, slightly rotated
    other = Biased(rpc.model, AffineBias((-31.4, 17.7), ((-0.06, 0.01), (-0.008, -0.055))))
    dem = read_dem(nice_dem_synthetic, height="ellipsoidal")
    images = [_render(m, dem, tmp_path / f"view{k}.tif") for k, m in enumerate((rpc, other))]
    tiles = TileSettings(progress=False)
    default = OrthoSettings(crs="EPSG:32632")
    reps = [orthorectify(im, dem, tmp_path / f"o{k}.tif", default, tiles, model=m)
            for k, (im, m) in enumerate(zip(images, (rpc, other), strict=True))]  # fmt: skip
    # at default settings: each its own GSD, one common resolution, pixels on one lattice
    assert abs(reps[1].gsd / reps[0].gsd - 1) > 0.05, [r.gsd for r in reps]  # 0.531, 0.500 m
    assert reps[0].res_m == reps[1].res_m == common_resolution(reps[0].gsd)
    for r in reps:
        for v in r.bounds:
            assert abs(v / r.res_m - round(v / r.res_m)) < 1e-6
    # the second view on the first one's grid: its transform and shape exactly
    like = tmp_path / "o0.tif"
    rep = orthorectify(images[1], dem, tmp_path / "like.tif", OrthoSettings(like=like), tiles,
                       model=other)  # fmt: skip
    with rasterio.open(like) as a, rasterio.open(tmp_path / "like.tif") as b:
        assert a.transform == b.transform and a.shape == b.shape and a.crs == b.crs
        p0, e0, n0 = a.read()
        p1, e1, n1 = b.read()
    assert (rep.width, rep.height) == (reps[0].width, reps[0].height)
    both = np.isfinite(e0) & np.isfinite(e1)
    assert both.mean() > 0.2, both.mean()
    # each pixel of both shows the same ground: the positions the two images saw there, 2 px
    # in from the edges of their data (where bilinear resampling has its own error: the
    # 99th percentile over all of it is 0.34 px); measured: mean 0.0002 px, 99 % 0.006 px
    inner = binary_erosion(both, iterations=2)
    miss = np.hypot(e0 - e1, n0 - n1)[inner] / rep.res_m
    p99 = np.percentile(miss, 99)
    assert miss.mean() < 0.05 and p99 < 0.3, (miss.mean(), p99)
    # and the painted pattern: phase correlation over a box where both have data (measured:
    # 0.014 px over 72 x 50 px)
    r, c = np.nonzero(inner)
    r0, r1, c0, c1 = r.min(), r.max() + 1, c.min(), c.max() + 1
    while not inner[r0:r1, c0:c1].all():  # shrunk from its bounding box
        r0, r1, c0, c1 = r0 + 1, r1 - 1, c0 + 1, c1 - 1
    assert min(r1 - r0, c1 - c0) >= 24, (r1 - r0, c1 - c0)
    box = (slice(r0, r1), slice(c0, c1))
    x, y = p0[box], p1[box]
    (dx, dy), _ = cv2.phaseCorrelate(
        x - x.mean(), y - y.mean(), cv2.createHanningWindow(x.shape[::-1], cv2.CV_64F)
    )
    assert math.hypot(dx, dy) < 0.1, (dx, dy)


VENTOUX = {"dem": "ventoux/dem/N44E005_srtm90.tif",
           "geoid": "ventoux/dem/egm96_15_crop_lon3-8_lat42-47.gtx"}  # fmt: skip


def _ortho(real_data, side, out, *extra):
    return main(["ortho", str(real_data / "ventoux" / f"{side}_image.tif"), "--model",
                 str(real_data / f"phr_ventoux__{side}_image.geom"),
                 "--dem", str(real_data / VENTOUX["dem"]), "--geoid",
                 str(real_data / VENTOUX["geoid"]), "-o", str(out), "--quiet", *extra])  # fmt: skip


@pytest.fixture(scope="module")
def ventoux_orthos(real_data, tmp_path_factory):
    """The Ventoux crops' orthoimages at default settings, and the right one on the left's grid
    and the left one on the right's."""
    d = tmp_path_factory.mktemp("ventoux")
    for side in ("left", "right"):
        assert _ortho(real_data, side, d / f"{side}.tif") == 0
    assert _ortho(real_data, "right", d / "right_like.tif", "--like", str(d / "left.tif")) == 0
    assert _ortho(real_data, "left", d / "left_like.tif", "--like", str(d / "right.tif")) == 0
    return d


def test_ventoux_orthos_share_a_grid_with_like(ventoux_orthos):
    d = ventoux_orthos
    with (rasterio.open(d / "left.tif") as left, rasterio.open(d / "right.tif") as right,
          rasterio.open(d / "right_like.tif") as like):  # fmt: skip
        # default: GSDs 0.499 and 0.520 m, both at 0.5 m on one lattice
        assert left.res == right.res == (0.5, 0.5)
        off = np.array([right.transform.c - left.transform.c, right.transform.f - left.transform.f])
        assert np.allclose(off / 0.5, np.round(off / 0.5), atol=1e-9) and left.shape != right.shape
        assert like.transform == left.transform and like.shape == left.shape
        assert like.crs == left.crs
    # the left image on the right one's grid: where it has data, its pixels are those of its
    # ortho on its own grid (the same ground under each pixel; measured: 99.9 % of 80 325 px
    # equal, the others 1 DN apart: the coarse grid's interpolation, 0.01 px at most)
    with rasterio.open(d / "left.tif") as own, rasterio.open(d / "left_like.tif") as moved:
        t0, t1 = own.transform, moved.transform
        dc, dr = round((t1.c - t0.c) / 0.5), round((t0.f - t1.f) / 0.5)
        a, b = own.read(1).astype(float), moved.read(1).astype(float)
    r0, c0 = max(dr, 0), max(dc, 0)
    r1, c1 = min(a.shape[0], dr + b.shape[0]), min(a.shape[1], dc + b.shape[1])
    a, b = a[r0:r1, c0:c1], b[r0 - dr : r1 - dr, c0 - dc : c1 - dc]
    both = (a > 0) & (b > 0)
    assert both.sum() > 10_000
    assert np.abs(a - b)[both].max() <= 1.0, np.abs(a - b)[both].max()  # uint16: rounding


LIKE_REFUSED = {
    "--res": ["--res", "0.5"],
    "--crs": ["--crs", "EPSG:32631"],
    "--bounds": ["--bounds", "675240", "4897000", "675400", "4897300"],
    "--no-tap": ["--no-tap"],
}


@pytest.mark.parametrize("option", LIKE_REFUSED)
def test_like_with_an_option_of_the_grid_is_refused(option, ventoux_orthos, real_data, tmp_path,
                                                    capsys):  # fmt: skip
    like = str(ventoux_orthos / "left.tif")
    assert _ortho(real_data, "right", tmp_path / "o.tif", "--like", like,
                  *LIKE_REFUSED[option]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert f"{option} cannot be given with it" in err and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []


def test_like_refusals_of_the_command(ventoux_orthos, real_data, tmp_path, capsys):
    image = real_data / "ventoux" / "right_image.tif"
    kept = tmp_path / "kept.tif"
    shutil.copy(ventoux_orthos / "left.tif", kept)
    before = kept.read_bytes()
    cases = [  # --like a satellite image (no map grid), the output onto the --like raster
        (["--like", str(image)], tmp_path / "o.tif", f"--like: {image}: this raster has no CRS"),
        (["--like", str(kept), "--overwrite"], kept, "is an input"),
    ]
    for extra, out, message in cases:
        assert _ortho(real_data, "right", out, *extra) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err and err.count("\n") == 1, err
        assert err.startswith("jaxgeo ortho: error: ")
    assert sorted(tmp_path.iterdir()) == [kept] and kept.read_bytes() == before
    # the DSM's: --like with --res
    args = ["dsm", str(image), str(image), "--like", str(ventoux_orthos / "left.tif"), "--res",
            "1", "-o", str(tmp_path / "dsm.tif"), "--quiet"]  # fmt: skip
    assert main(args) == 2
    assert "--res cannot be given with it" in capsys.readouterr().err
    # and a raster whose grid a DSM cannot have (degrees), named as the option
    geo = _write(tmp_path / "geo.tif", "EPSG:4326", Affine(1e-5, 0, 5.1, 0, -1e-5, 44.3))
    args[args.index("--like") + 1 : args.index("--like") + 4] = [str(geo)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"jaxgeo dsm: error: --like: {geo}: its CRS (WGS 84) is not a projected" in err, err


def test_dsm_grid_is_target_aligned_or_like(ventoux_orthos, real_data):
    images = [open_image(real_data / "ventoux" / f"{s}_image.tif",
                         model=real_data / f"phr_ventoux__{s}_image.geom")
              for s in ("left", "right")]  # fmt: skip
    models, paths = [im.model for im in images], [im.path for im in images]
    heights = (900.0, 1300.0)  # given: nothing matched
    tap = plan_dsm(models, paths, DSMSettings(res_m=0.5, heights=heights)).job.spec.transform
    assert all(abs(v / 0.5 - round(v / 0.5)) < 1e-9 for v in (tap[2], tap[5]))
    free = plan_dsm(models, paths, DSMSettings(res_m=0.5, heights=heights, tap=False))
    x0, y0 = free.job.spec.transform[2], free.job.spec.transform[5]
    assert 0 < x0 - tap[2] < 0.5 and 0 < tap[5] - y0 < 0.5  # inside the aligned corner
    like = ventoux_orthos / "left.tif"
    setup = plan_dsm(models, paths, DSMSettings(heights=heights, like=like))
    with rasterio.open(like) as src:
        assert Affine(*setup.job.spec.transform) == src.transform
        assert (setup.plan.width, setup.plan.height) == (src.width, src.height)
    far = OutputGrid(pyproj.CRS.from_epsg(32631), 0.5, 600000.0, 4800000.0, 64, 64)
    with pytest.raises(StereoError, match="misses the footprint"):
        plan_dsm(models, paths, DSMSettings(heights=heights, like=far))


def test_plan_ortho_like_keeps_the_grid_and_refuses_one_without_the_image(
    ventoux_orthos, real_data, tmp_path
):
    dem = read_dem(real_data / VENTOUX["dem"], geoid=real_data / VENTOUX["geoid"])
    image = open_image(real_data / "ventoux" / "right_image.tif",
                       model=real_data / "phr_ventoux__right_image.geom")  # fmt: skip
    like = OutputGrid.of_raster(ventoux_orthos / "left.tif")
    setup = plan_ortho(image, dem, tmp_path / "o.tif", OrthoSettings(like=like))
    assert Affine(*setup.job.spec.transform) == like.transform and setup.bounds == like.bounds
    far = OutputGrid("EPSG:32631", 0.5, 600000.0, 4800000.0, 64, 64)  # any CRS pyproj takes
    with pytest.raises(OrthoError, match="the grid given \\(like\\) W S E N .* lies outside"):
        plan_ortho(image, dem, tmp_path / "o.tif", OrthoSettings(like=far))
