"""Pixel frames of crops (docs/conventions.md) and ``adjusted_models.json`` read as a model file.

``reframed(model, d)`` moves a model to pixels shifted by ``d``, exactly, for an RPC and an RPC
with every bias kind (a jitter included); an adjusted model written to ``adjusted_models.json``
in its product's frame and opened with a crop projects like the in-memory crop model.
"""

import json

import numpy as np
import pytest

from jaxgeo.bundle._models_json import framed_models, models_json
from jaxgeo.io import ImageError, RPCFormatError, open_image, read_rpc
from jaxgeo.io._adjusted import read_adjusted_model
from jaxgeo.io.internal import reframed
from jaxgeo.models import RPC, AffineBias, Biased, JitterBias, ShiftBias, ShiftDriftBias
from tests.conftest import REAL_DATA as REAL

GEOM = REAL / "phr_ventoux__left_image.geom"
CROP = REAL / "ventoux" / "left_image.tif"  # pixel (0, 0) at product pixel (5000, 5000)
ORIGIN = (5000.0, 5000.0)
GROUND = np.array(
    [[5.19399, 44.20831, 900.0], [5.19540, 44.20773, 1100.0], [5.19642, 44.20655, 700.0]]
)  # on the crop (near pixels 50..450)


def _biases():
    jitter = JitterBias((-0.5, 499.5), 60.0, 0.5, (1.2, -0.7), ((2e-4, -1e-4), (3e-5, 1e-4)))
    n = jitter.knots_px.shape[0]
    knots = np.stack([np.sin(np.arange(n)), 0.6 * np.cos(1.3 * np.arange(n))], axis=1)
    jitter = JitterBias((-0.5, 499.5), 60.0, 0.5, jitter.shift_px, jitter.matrix, knots)
    return {
        "shift": ShiftBias((1.5, -2.25)),
        "shift-drift": ShiftDriftBias((1.5, -2.25), (3e-4, -2e-4)),
        "affine": AffineBias((1.5, -2.25), ((1e-4, -2e-4), (5e-5, 3e-4))),
        "jitter": jitter,
    }


@pytest.fixture(scope="module")
def crop_rpc():
    return open_image(CROP, model=GEOM).model  # the product's RPC in the crop's pixels


@pytest.mark.parametrize("kind", ["shift", "shift-drift", "affine", "jitter"])
def test_reframed_both_ways_every_bias(crop_rpc, kind):
    crop_model = Biased(crop_rpc, _biases()[kind])
    product = reframed(crop_model, ORIGIN)
    assert isinstance(product, Biased) and type(product.bias) is type(crop_model.bias)
    in_crop = np.asarray(crop_model.project(GROUND))
    assert np.all(np.abs(in_crop - 250) < 400)  # the points fall on the crop
    np.testing.assert_allclose(np.asarray(product.project(GROUND)), in_crop + ORIGIN, atol=1e-9)
    back = reframed(product, (-ORIGIN[0], -ORIGIN[1]))
    np.testing.assert_allclose(np.asarray(back.project(GROUND)), in_crop, atol=1e-9)


def test_reframed_other_models_and_zero():
    inner = Biased(read_rpc(GEOM), ShiftBias((0.0, 0.0)))
    generic = Biased(inner, ShiftBias((3.0, 4.0)))  # wrapped again: recursion keeps it exact
    moved = reframed(generic, (-10.0, 20.0))
    np.testing.assert_allclose(
        np.asarray(moved.project(GROUND)),
        np.asarray(generic.project(GROUND)) + (-10.0, 20.0),
        atol=1e-9,
    )
    assert reframed(generic, (0.0, 0.0)) is generic


class _Result:
    """What :func:`models_json` reads of an adjustment: the adjusted and the start models."""

    def __init__(self, models, start):
        self.models = models
        self.blocks = {n: None for n in models}
        self.setup = _Setup(start)
        self.param_names, self.param_cov = [], None

    def parameters(self, key):
        return {}


class _Setup:
    def __init__(self, start):
        self.start = start
        self.problem = type("P", (), {"groups": ()})()

    def image_models(self, groups, thetas):
        return self.start


def _written(tmp_path, models, start, origins):
    path = tmp_path / "adjusted_models.json"
    path.write_text(json.dumps(models_json(_Result(models, start), origins)))
    return path


@pytest.mark.parametrize("kind", ["shift", "affine", "jitter"])
def test_adjusted_models_json_read_with_the_crop(tmp_path, crop_rpc, kind):
    """The JSON holds the model in the product's frame; opened with the crop (whose
    geotransform applies), it projects like the in-memory crop model, to 1e-9 px."""
    adjusted = Biased(crop_rpc, _biases()[kind])
    path = _written(tmp_path, {"left_image": adjusted, "right_image": crop_rpc},
                    {"left_image": crop_rpc, "right_image": crop_rpc},
                    {"left_image": ORIGIN, "right_image": ORIGIN})  # fmt: skip
    entry = json.loads(path.read_text())["images"]["left_image"]
    assert entry["bias"]["kind"] == type(adjusted.bias).__name__
    # in the product's frame: the delivered RPC's offsets, not the crop's
    np.testing.assert_allclose([entry["rpc"]["samp_off"], entry["rpc"]["line_off"]],
                               np.asarray(read_rpc(GEOM).image_offset), atol=1e-9)  # fmt: skip
    image = open_image(CROP, model=path)  # named by the raster's stem
    assert image.name == "left_image" and image.origin == ORIGIN
    # a pure shift is folded into the RPC (its compiled kernel), any other bias kept
    assert isinstance(image.source_model, RPC if kind == "shift" else Biased)
    np.testing.assert_allclose(np.asarray(image.model.project(GROUND)),
                               np.asarray(adjusted.project(GROUND)), atol=1e-9)  # fmt: skip
    # the model alone: the product's frame
    alone = open_image(model=path, name="left_image")
    np.testing.assert_allclose(
        np.asarray(alone.model.project(GROUND)),
        np.asarray(adjusted.project(GROUND)) + ORIGIN,
        atol=1e-9,
    )
    framed = framed_models(_Result({"left_image": adjusted}, {}), {"left_image": ORIGIN})
    np.testing.assert_allclose(
        np.asarray(framed["left_image"].project(GROUND)),
        np.asarray(alone.model.project(GROUND)),
        atol=1e-9,
    )


def test_adjusted_models_json_names(tmp_path, crop_rpc):
    affine = AffineBias((1.0, 2.0), ((1e-4, 0.0), (0.0, -1e-4)))
    two = _written(tmp_path, {"a": Biased(crop_rpc, affine), "b": crop_rpc},
                   {"a": crop_rpc, "b": crop_rpc}, {})  # fmt: skip
    with pytest.raises(RPCFormatError, match=r"no image named 'left_image'; it holds a, b"):
        open_image(CROP, model=two)
    with pytest.raises(RPCFormatError, match=r"several images \(a, b\): name the image"):
        read_adjusted_model(two)  # no name, several images
    assert isinstance(open_image(CROP, model=two, name="a").source_model, Biased)
    # read_rpc would drop the bias: refused, saying how to read it
    with pytest.raises(RPCFormatError, match="an adjusted_models.json"):
        read_rpc(two)
    one = tmp_path / "one" / "adjusted_models.json"
    one.parent.mkdir()
    one.write_text(json.dumps({"images": {"a": json.loads(two.read_text())["images"]["a"]}}))
    assert open_image(CROP, model=one).name == "left_image"  # a file of one image: its entry
    bad = json.loads(two.read_text())
    bad["images"]["a"]["bias"]["kind"] = "Wobble"
    one.write_text(json.dumps(bad))
    with pytest.raises(RPCFormatError, match=r"image 'a': bias kind 'Wobble' unknown"):
        open_image(CROP, model=one, name="a")


def test_raster_own_rpc_is_in_its_own_pixels(tmp_path):
    """A raster's own RPC (tags or sidecar) is in its pixels: a pixel-space geotransform's
    origin is not applied to it (GDAL's rule); a separate model file gets it."""
    import shutil
    import warnings

    import rasterio

    from jaxgeo.io import write_rpc_text

    crop = tmp_path / "crop.tif"
    shutil.copy(CROP, crop)
    rpc = open_image(CROP, model=GEOM).model  # the crop's own RPC
    write_rpc_text(rpc, tmp_path / "crop_RPC.TXT")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(crop) as src:
            assert tuple(src.transform)[:6] == (1.0, 0.0, 5000.0, 0.0, 1.0, 5000.0)
    own = open_image(crop)
    assert own.origin == (0.0, 0.0)
    np.testing.assert_allclose(np.asarray(own.model.project(GROUND)),
                               np.asarray(rpc.project(GROUND)), atol=1e-9)  # fmt: skip
    separate = open_image(crop, model=GEOM)
    assert separate.origin == ORIGIN
    np.testing.assert_allclose(np.asarray(separate.model.project(GROUND)),
                               np.asarray(rpc.project(GROUND)), atol=1e-9)  # fmt: skip
    with pytest.raises(ImageError, match="conflicts with the crop origin"):
        open_image(crop, model=GEOM, origin=(0, 0))
