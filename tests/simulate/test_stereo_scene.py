"""Scene-size simulated truth (``jaxgeo.simulate.stereo_scene``): files, RPCs against the true
models, jitter, determinism, refusal to overwrite, and the block renderer."""

import json
import warnings

import numpy as np
import pytest
import rasterio
from rasterio.errors import NotGeoreferencedWarning
from rasterio.transform import RPCTransformer

from jaxgeo.io import read_rpc
from jaxgeo.models import localize_points, project_points
from jaxgeo.simulate import (
    JitteredModel,
    SimulationError,
    StereoSceneSettings,
    read_stereo_scene,
    stereo_scene,
    stereo_scene_truth,
)
from jaxgeo.simulate._stereo_scene import stereo_scene_files
from jaxgeo.simulate._stereo_scene_models import localize_on_terrain_exact, project_true
from jaxgeo.simulate._stereo_scene_render import (
    TILE,
    RenderedImage,
    render_window,
    scene_windows,
    window_ground,
    write_blocks,
)

SIZE = 256
JITTER_PX, PERIOD = 1.5, 100.0  # 2.5 periods over the image


@pytest.fixture(scope="module")
def jittered(tmp_path_factory):
    """A written scene with jitter and exact RPCs, and its truth read back from the folder."""
    out = tmp_path_factory.mktemp("jittered")
    settings = StereoSceneSettings(jitter_px=JITTER_PX, jitter_period_lines=PERIOD, exact_rpc=True)
    scene = stereo_scene(out, SIZE, 11, settings)
    return out, scene, read_stereo_scene(out)


def test_files_dtypes_and_tags(jittered):
    out, scene, _ = jittered
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in
                                                            stereo_scene_files(out))  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        for name in ("left", "right"):
            with rasterio.open(out / f"{name}.tif") as src:
                assert (src.count, src.width, src.height) == (1, SIZE, SIZE)
                assert src.dtypes[0] == "uint16" and src.block_shapes == [(TILE, TILE)]
                assert src.crs is None and src.transform.is_identity  # no geotransform
                assert src.rpcs is not None  # GDAL reads the RPC tag
                img = src.read(1)
            assert 0 < img.min() and img.max() <= 4095 and img.std() > 200  # textured 12 bits
    with rasterio.open(out / "truth_dsm.tif") as src:
        assert src.dtypes[0] == "float32" and np.isnan(src.nodata)
        assert src.crs.to_epsg() == scene.dsm.epsg == 32631
        assert src.res == (scene.dsm.res_m, scene.dsm.res_m)
        assert abs(scene.dsm.res_m - scene.info["gsd_m"]) < 0.05  # cells of about the GSD
        dsm = src.read(1)
        valid = np.isfinite(dsm)
        assert 0.4 < valid.mean() < 0.95  # NaN outside the common footprint
        lo, hi = float(scene.terrain.h_min_m), float(scene.terrain.h_max_m)
        assert lo - 1 < dsm[valid].min() and dsm[valid].max() < hi + 1
        # the truth points lie on the DSM (cell of each point: height within the cell's slope)
        import pyproj

        tr = pyproj.Transformer.from_crs(4326, src.crs.to_epsg(), always_xy=True)
        x, y = tr.transform(scene.points[:, 0], scene.points[:, 1])
        row, col = rasterio.transform.rowcol(src.transform, x, y)
        assert np.abs(dsm[row, col] - scene.points[:, 2]).max() < 0.3
    truth = json.loads((out / "truth.json").read_text())
    assert set(truth["images"]) == {"left", "right"}
    assert 0.6 < truth["gsd_m"] < 0.7 and 0.3 < truth["base_to_height"] < 0.5
    assert len(truth["points"]["lonlath"]) > 150


def test_rpc_projects_truth_points_to_the_true_pixel(jittered):
    out, scene, back = jittered
    for name in ("left", "right"):
        rpc = read_rpc(out / f"{name}.tif")  # the GeoTIFF tag, as a user reads it
        xy = np.asarray(rpc.project(back.points))
        true = project_points(back.base[name], back.points)  # the jitter-free true model
        assert np.abs(xy - true).max() < 0.05  # measured 1e-5 px (12-digit coefficients)
        with warnings.catch_warnings():  # GDAL reads the same RPC (its pixel = ours + 0.5)
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(out / f"{name}.tif") as src, RPCTransformer(src.rpcs) as tr:
                p = back.points
                row, col = tr.rowcol(p[:, 0], p[:, 1], zs=p[:, 2], op=lambda v: v)
        assert np.abs(np.stack([col, row], -1) - 0.5 - true).max() < 0.05
        np.testing.assert_allclose(true, back.info["xy_nojitter"][name], atol=1e-5)
        fit = back.info["rpc_fit"][name]
        assert fit["check_max_px"] < 0.05 and back.info["rpc_vs_truth"][name]["nojitter_px"][
            "max"] < 0.05  # fmt: skip
    # the models read back are those the scene was made with
    g = scene.points[:5]
    for name in ("left", "right"):
        np.testing.assert_allclose(project_true(back.truth[name], g),
                                   project_true(scene.truth[name], g), atol=1e-9)  # fmt: skip


def test_vendor_rpcs_carry_a_few_pixels_of_bias():
    scene = stereo_scene_truth(128, 4)
    for name in ("left", "right"):
        vs = scene.info["rpc_vs_truth"][name]["nojitter_px"]
        assert 0.3 < vs["rms"] < 10.0  # a realistic pointing error
        assert scene.info["rpc_fit"][name]["check_max_px"] < 0.05  # to the vendor's model


def test_jitter_moves_the_true_model_at_its_period_not_the_rpc(jittered):
    out, scene, back = jittered
    rpc = read_rpc(out / "left.tif")
    truth, base = back.truth["left"], back.base["left"]
    assert isinstance(truth, JitteredModel)
    # ground points along a column of the left image, every 4 lines
    xy = np.stack([np.full(64, 128.0), np.arange(0.0, 256.0, 4.0)], -1)
    ground = localize_on_terrain_exact(base, back.terrain, xy)
    at_base = project_points(base, ground)
    d_true = project_points(truth, ground) - at_base
    d_rpc = np.asarray(rpc.project(ground)) - at_base
    y = project_points(truth, ground)[:, 1]
    w = 2 * np.pi / PERIOD
    design = np.stack([np.sin(w * y), np.cos(w * y), np.ones_like(y)], -1)
    for axis, amplitude in ((0, JITTER_PX), (1, JITTER_PX / 4)):
        coef, *_ = np.linalg.lstsq(design, d_true[:, axis], rcond=None)
        assert np.hypot(*coef[:2]) == pytest.approx(amplitude, rel=1e-6)
        assert np.abs(design @ coef - d_true[:, axis]).max() < 1e-6  # a sinusoid of period P
        coef, *_ = np.linalg.lstsq(design, d_rpc[:, axis], rcond=None)
        assert np.hypot(*coef[:2]) < 1e-3  # the delivered RPC holds none of it
    # project and localise of the jittered model are inverse (the renderer uses localise)
    back_xy = project_points(truth, localize_points(truth, xy, 350.0))
    assert np.abs(back_xy - xy).max() < 1e-8


def test_rendered_pixels_see_the_terrain_through_the_jittered_model(jittered):
    _, scene, _ = jittered
    model, terrain = scene.truth["right"], scene.terrain
    lonlat = window_ground(model, terrain, (100, 164, -3, 61)).reshape(-1, 2)  # rows, cols
    yy, xx = np.mgrid[100:164, -3:61]
    xy = np.stack([xx.ravel(), yy.ravel()], -1).astype(float)
    exact = localize_on_terrain_exact(model, terrain, xy)
    h = terrain.height_np(lonlat)
    back = project_points(model, np.concatenate([lonlat, h[:, None]], -1))
    assert np.abs(back - xy).max() < 2e-3  # lines of sight interpolated from nodes every 8 px
    assert np.abs(h - exact[:, 2]).max() < 5e-3


def test_same_seed_same_bytes_and_refusal_to_overwrite(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    stereo_scene(a, 128, 5)
    stereo_scene(b, 128, 5)
    for name in ("left.tif", "right.tif", "truth_dsm.tif", "truth.json"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    before = {p.name: p.read_bytes() for p in a.iterdir()}
    with pytest.raises(FileExistsError, match="refusing to overwrite.*left.tif"):
        stereo_scene(a, 128, 6)
    assert {p.name: p.read_bytes() for p in a.iterdir()} == before
    stereo_scene(a, 128, 6, overwrite=True)
    assert (a / "left.tif").read_bytes() != (b / "left.tif").read_bytes()  # another seed
    assert json.loads((a / "truth.json").read_text())["params"]["seed"] == 6
    assert sorted(p.name for p in a.iterdir()) == sorted(before)  # no temporary file left


def test_block_renderer_is_independent_of_the_windowing(jittered):
    _, scene, _ = jittered
    blocks = scene_windows(SIZE, SIZE, TILE, TILE)
    assert blocks == [[(0, 256, 0, 256)]]
    assert scene_windows(600, 520, 256, 512) == [
        [(0, 256, 0, 512), (0, 256, 512, 520)],
        [(256, 512, 0, 512), (256, 512, 512, 520)],
        [(512, 600, 0, 512), (512, 600, 512, 520)],
    ]
    with pytest.raises(ValueError, match="multiples of 256"):
        scene_windows(100, 100, 100, 256)
    kw = dict(settings=scene.render)
    args = (scene.truth["right"], scene.terrain, scene.texture)
    image = RenderedImage(seed=11, index=1, gain=0.97)
    top = render_window(*args, (0, 100, 0, 256), image, **kw)  # windows of any size, anywhere
    bottom = render_window(*args, (100, 256, 0, 256), image, **kw)
    assert top.shape == (100, 256) and top.dtype == np.uint16
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(jittered[0] / "right.tif") as src:  # one 256 x 256 window
            np.testing.assert_array_equal(src.read(1), np.concatenate([top, bottom]))

    class Recorder:  # write_blocks writes every window once, where it belongs
        def __init__(self):
            self.windows = []

        def write(self, data, band, window):
            self.windows.append((window.row_off, window.col_off, *data.shape))

    rec, rows = Recorder(), []
    blocks = scene_windows(600, 520, 256, 512)
    write_blocks(rec, blocks, lambda w: np.zeros((w[1] - w[0], w[3] - w[2])),
                 lambda: rows.append(1))  # fmt: skip
    assert rec.windows == [(r0, c0, r1 - r0, c1 - c0) for row in blocks
                           for r0, r1, c0, c1 in row] and len(rows) == 3  # fmt: skip


@pytest.mark.parametrize(
    "kwargs, setting, message",
    [
        (dict(size=32), "size", "{} must be an integer >= 64"),
        (dict(seed=-1), "seed", "{} must be an integer >= 0"),
        (dict(jitter_px=-1.0), "jitter_px", "{} must be >= 0"),
        (dict(jitter_period_lines=5.0), "jitter_period_lines", "{} must be >= 10"),
        (dict(jitter_px=10.0, jitter_period_lines=50.0), "jitter_px", "folds the image"),
        (dict(relief_m=0.0), "relief_m", "{} must be in"),
    ],
)
def test_bad_options_are_named(kwargs, setting, message):
    """The library names the setting (the field of StereoSceneSettings, or the argument), the
    command its option (``err.render``, as ``jaxgeo simulate stereo-scene`` does)."""
    from jaxgeo.cli._simulate import OPTIONS

    kwargs = {"size": 128, "seed": 0} | kwargs
    size, seed = kwargs.pop("size"), kwargs.pop("seed")
    with pytest.raises(SimulationError) as err:
        stereo_scene_truth(size, seed, StereoSceneSettings(**kwargs))
    assert err.value.setting == setting
    assert message.format(setting) in str(err.value)
    assert message.format(OPTIONS[setting]) in err.value.render(OPTIONS)
