"""Pre-flight checks name the point, image (and file and line) at fault, before any solve; a
fit far from the a priori sigmas (two RPCs swapped) is a warning naming images and points."""

import dataclasses
import warnings

import numpy as np
import pytest

from jaxgeo.bundle import AdjustmentError, PoorFitWarning, adjust
from jaxgeo.io import GroundPoints, Observations


def _moved(ground, pid, d_lonlath):
    lonlath = ground.lonlath.copy()
    lonlath[ground.ids.index(pid)] += d_lonlath
    return dataclasses.replace(ground, lonlath=lonlath)


def test_gcp_a_degree_outside_the_rpc_domain(block):
    ground = _moved(block.ground, "P01", [1.0, 0.0, 0.0])
    with pytest.raises(
        AdjustmentError, match=r"'P01' \(gcp\) lies outside the validity domain"
    ) as e:
        adjust(block.models, block.obs, ground, bias="affine")
    assert "longitude" in str(e.value) and "deg beyond" in str(e.value)


def test_gcp_50_km_high(block):
    ground = _moved(block.ground, "P03", [0.0, 0.0, 50e3])
    with pytest.raises(AdjustmentError, match=r"'P03'.*its height .* m is .* m beyond"):
        adjust(block.models, block.obs, ground, bias="affine")


def test_measurement_outside_the_image(block):
    xy = block.obs.xy.copy()
    xy[5] = [-3000.0, 100.0]
    obs = dataclasses.replace(block.obs, xy=xy)
    with pytest.raises(AdjustmentError, match=r"observation 5: point 'P05'.*px outside image"):
        adjust(block.models, obs, block.ground, bias="affine")


def test_point_twice_in_one_image_contradictory(block):
    o = block.obs
    obs = Observations(
        o.point_ids + ("P04",),
        o.images + ("left",),
        np.vstack([o.xy, o.xy[4] + [20.0, 0.0]]),
        np.append(o.sigma_px, 0.3),
    )
    with pytest.raises(
        AdjustmentError, match="'P04' is measured twice in image 'left'.*contradictory"
    ):
        adjust(block.models, obs, block.ground, bias="affine")


def test_gcp_id_twice(block):
    g = block.ground
    ground = GroundPoints(
        g.ids + ("P00",), np.vstack([g.lonlath, g.lonlath[:1]]), g.role + ("gcp",),
        np.vstack([g.sigma_m, g.sigma_m[:1]]),
    )  # fmt: skip
    with pytest.raises(AdjustmentError, match="'P00' is given twice"):
        adjust(block.models, block.obs, ground, bias="affine")


def test_swapped_models_warn_with_images_and_cause(block):
    swapped = {"left": block.models["right"], "right": block.models["left"]}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = adjust(swapped, block.obs, block.ground, bias="affine")
    poor = [w for w in caught if issubclass(w.category, PoorFitWarning)]
    assert len(poor) == 1
    text = str(poor[0].message)
    assert "Worst images: " in text and "Likely cause: the residuals are systematic" in text
    assert r.removed.sum() <= 0.2 * len(block.obs.point_ids)  # not cut away as gross errors
