"""A crop of a simulated jittered scene adjusted with a jitter bias, its written models read back
(issue 51): ``adjusted_models.json`` is in the product's frame, opened with the crop (the
geotransform's origin applied once) it projects like the in-memory adjusted model to 1e-9 px,
and against truth it puts the true points on their true pixels in the crop.

The pair is :func:`jaxgeo.simulate.stereo_scene_truth` (400 px, a 1.5 px jitter of period 200
lines, exact RPCs fitted without it; seed 5151, used nowhere else), not rendered: ties are
terrain points projected through the true models plus 0.1 px of noise; each image is then a
"crop" at origin (100, 150) of that product: a sparse raster with a pixel-space geotransform,
its measurements in its own pixels, its model the product's RPC file. And ``adjust`` from an
adjusted model (an ``adjusted_models.json`` entry) starts the new bias from the old one.
"""

import warnings

import numpy as np
import pytest
import rasterio
from affine import Affine

from jaxgeo.bundle import AdjustSettings, JitterSettings, adjust_files
from jaxgeo.io import open_image, write_rpc_text
from jaxgeo.lsq import SolverConfig
from jaxgeo.models import Biased, JitterBias
from jaxgeo.simulate import StereoSceneSettings, stereo_scene_truth
from jaxgeo.simulate._stereo_scene_models import localize_on_terrain_exact, project_true

SIZE, PERIOD, SEED, NOISE_PX = 400, 200.0, 5151, 0.1
ORIGIN = np.array([100.0, 150.0])
NAMES = ("left", "right")


def _crop(path, origin):
    profile = dict(
        driver="GTiff",
        width=SIZE - int(origin[0]),
        height=SIZE - int(origin[1]),
        count=1,
        dtype="uint8",
        tiled=True,
        blockxsize=256,
        blockysize=256,
        sparse_ok=True,
        transform=Affine(1.0, 0.0, origin[0], 0.0, 1.0, origin[1]),
    )
    with warnings.catch_warnings():  # a pixel-space geotransform, no CRS: on purpose
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path, "w", **profile):
            pass
    return path


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("crop_jitter")
    scene = stereo_scene_truth(SIZE, SEED, StereoSceneSettings(
        jitter_px=1.5, jitter_period_lines=PERIOD, exact_rpc=True))  # fmt: skip
    g = np.linspace(ORIGIN.max() + 5, SIZE - 6, 24)
    xy1 = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    ground = localize_on_terrain_exact(scene.truth["left"], scene.terrain, xy1)
    xy2 = np.asarray(project_true(scene.truth["right"], ground))
    keep = np.all(np.isfinite(ground), axis=1) & np.all((xy2 > ORIGIN + 2) & (xy2 < SIZE - 3), 1)
    xy = {"left": xy1[keep], "right": xy2[keep]}
    rng = np.random.default_rng(SEED)
    lines = ["id,image,x,y,sigma_px"]
    images = {}
    for name in NAMES:
        write_rpc_text(scene.rpcs[name], folder / f"{name}_product_RPC.TXT")
        crop = _crop(folder / f"{name}.tif", ORIGIN)
        images[name] = open_image(crop, model=folder / f"{name}_product_RPC.TXT", name=name)
        noisy = xy[name] - ORIGIN + rng.normal(0, NOISE_PX, xy[name].shape)  # crop pixels
        lines += [f"T{i:04d},{name},{x:.4f},{y:.4f},0.2" for i, (x, y) in enumerate(noisy)]
    (folder / "obs.csv").write_text("\n".join(lines) + "\n")
    settings = AdjustSettings(jitter=JitterSettings(PERIOD / 8, 0.3))
    run = adjust_files(images, folder / "obs.csv", bias="jitter",
                       solver=SolverConfig(loss="l2", remove_blunders=False),
                       settings=settings)  # fmt: skip
    assert run.result.converged
    run.write(folder / "out")
    truth = ground[keep]
    return scene, run, folder, truth


def test_adjusted_models_json_projects_like_the_adjusted_model(adjusted):
    scene, run, folder, truth = adjusted
    for name in NAMES:
        memory = run.result.models[name]  # in the crop's pixels
        assert isinstance(memory, Biased) and isinstance(memory.bias, JitterBias)
        read = open_image(folder / f"{name}.tif", model=folder / "out" / "adjusted_models.json")
        assert read.name == name and read.origin == tuple(ORIGIN)
        assert isinstance(read.model.bias, JitterBias)  # the jitter is applied, not dropped
        np.testing.assert_allclose(np.asarray(read.model.project(truth)),
                                   np.asarray(memory.project(truth)), atol=1e-9)  # fmt: skip
        # the file is in the product's frame: without the crop, product pixels
        alone = open_image(model=folder / "out" / "adjusted_models.json", name=name)
        np.testing.assert_allclose(
            np.asarray(alone.model.project(truth)),
            np.asarray(memory.project(truth)) + ORIGIN,
            atol=1e-9,
        )


def test_adjusted_crop_models_put_the_truth_on_its_pixels(adjusted):
    """The true points through the models read back land on their true crop pixels: to the
    noise, with the jitter corrected (the delivered RPCs miss by the jitter and the vendor's
    pointing)."""
    scene, run, folder, truth = adjusted
    for name in NAMES:
        want = np.asarray(project_true(scene.truth[name], truth)) - ORIGIN
        read = open_image(folder / f"{name}.tif", model=folder / "out" / "adjusted_models.json")
        given = open_image(folder / f"{name}.tif", model=folder / f"{name}_product_RPC.TXT")
        rms = {k: float(np.sqrt(np.mean((np.asarray(m.model.project(truth)) - want) ** 2)))
               for k, m in (("adjusted", read), ("given", given))}  # fmt: skip
        # measured (2-core VM): given 0.78 / 0.74 px (the jitter), adjusted 0.28 / 0.30 px (a
        # relative orientation: what the ties leave open is held at the given models)
        assert rms["given"] > 0.5
        assert rms["adjusted"] < 0.4 and rms["adjusted"] < 0.5 * rms["given"]


def test_a_start_model_already_adjusted_restarts_its_bias():
    """``adjust`` from an ``adjusted_models.json`` entry: the new bias starts from the old one's
    values (the priors then hold the block near the adjusted model), or says why it cannot."""
    from jaxgeo.bundle._files import restarted
    from jaxgeo.models import AffineBias, ShiftBias, ShiftDriftBias
    from tests.conftest import REAL_DATA

    rpc = open_image(model=REAL_DATA / "phr_ventoux__left_image.geom").model
    domain = {"a": (-0.5, -0.5, 499.5, 499.5)}
    jitter = JitterSettings(100.0, 1.0)
    drift = Biased(rpc, ShiftDriftBias((1.0, -2.0), (1e-4, -3e-4)))
    new = restarted({"a": drift}, "affine", domain, jitter)["a"]
    assert isinstance(new.bias, AffineBias) and new.model is rpc
    ground = np.asarray(rpc.localize(np.array([[10.0, 20.0], [400.0, 300.0]]), 900.0))
    np.testing.assert_allclose(np.asarray(new.project(ground)),
                               np.asarray(drift.project(ground)), atol=1e-9)  # fmt: skip
    with pytest.raises(ValueError, match=r"image 'a': .* --bias shift cannot hold"):
        restarted({"a": drift}, "shift", domain, jitter)
    as_jitter = restarted({"a": drift}, "jitter", domain, jitter)["a"]
    np.testing.assert_allclose(np.asarray(as_jitter.project(ground)),
                               np.asarray(drift.project(ground)), atol=1e-9)  # fmt: skip
    # a jitter: kept by a jitter of another knot layout (least squares), refused by any other
    old = as_jitter.bias
    knots = np.stack([np.sin(np.arange(old.knots_px.shape[0]))] * 2, axis=1) * 0.5
    wavy = Biased(rpc, JitterBias((-0.5, 499.5), 100.0, 1.0, old.shift_px, old.matrix, knots))
    same = restarted({"a": wavy}, "jitter", domain, jitter)["a"]
    np.testing.assert_allclose(np.asarray(same.project(ground)),
                               np.asarray(wavy.project(ground)), atol=1e-9)  # fmt: skip
    finer = restarted({"a": wavy}, "jitter", domain, JitterSettings(50.0, 1.0))["a"]
    np.testing.assert_allclose(np.asarray(finer.project(ground)),
                               np.asarray(wavy.project(ground)), atol=1e-6)  # fmt: skip
    with pytest.raises(ValueError, match="would drop it: use --bias jitter"):
        restarted({"a": wavy}, "affine", domain, jitter)
    plain = restarted({"a": rpc}, "shift", domain, jitter)["a"]  # a model without a bias
    assert isinstance(plain.bias, ShiftBias) and not np.any(np.asarray(plain.bias.shift_px))
