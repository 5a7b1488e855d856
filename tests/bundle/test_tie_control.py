"""Blocks controlled through tie points: no per-image GCP count; what GCPs and ties leave open is
named from the normal equations, or fixed by bias priors.

Ventoux pair, shift bias; the right image's GCP measurements are dropped, so the right image is
connected to the ground only through the two-ray points. Its bias across the epipolar direction
is fixed by the ties; along it, a shift of the right image trades against the heights of the
tie points (parallax), so it stays open unless a prior (or a GCP in the image) fixes it.
"""

import numpy as np
import pytest

from jaxgeo.bundle import (
    AdjustSettings,
    SingularNormalEquations,
    TooFewControlPoints,
    adjust,
    with_bias,
)
from jaxgeo.bundle._adjustment import bias_prior_sigma
from jaxgeo.io import Observations


def _without_right_gcps(block, keep=()):
    gcps = {p for p, r in zip(block.ground.ids, block.ground.role, strict=True) if r == "gcp"}
    o = block.obs
    sel = [
        i
        for i, (p, img) in enumerate(zip(o.point_ids, o.images, strict=True))
        if not (img == "right" and p in gcps and p not in keep)
    ]
    return Observations(
        tuple(o.point_ids[i] for i in sel), tuple(o.images[i] for i in sel), o.xy[sel],
        o.sigma_px[sel],
    )  # fmt: skip


def test_what_ties_leave_open_is_named(block):
    obs = _without_right_gcps(block)
    with pytest.raises(TooFewControlPoints):  # the old per-image count rule, on request
        adjust(block.models, obs, block.ground, bias="shift",
               settings=AdjustSettings(check_control=True))  # fmt: skip
    with pytest.raises(SingularNormalEquations) as err:
        adjust(block.models, obs, block.ground, bias="shift")
    named = err.value.parameters
    assert named and all(p.startswith("right.bias.shift_px") for p in named)
    # and the direction: the right image's shift trades against the tie heights (parallax)
    msg = str(err.value)
    assert "direction 1:" in msg and "right.bias.shift_px" in msg
    assert "tie point heights" in msg and "parallax" in msg and "--dem" in msg


def test_tie_heights_from_a_dem_fix_it(block):
    obs = _without_right_gcps(block)
    gcp_h = block.ground.lonlath[:, 2]
    r = adjust(  # the check points are tie points here
        block.models, obs, block.ground.select("gcp"), bias="shift",
        settings=AdjustSettings(
            tie_height=lambda lonlat: np.full(len(lonlat), float(np.mean(gcp_h))),
            tie_height_sigma_m=300.0,
        ),
    )  # fmt: skip
    assert r.converged and np.all(np.isfinite(r.param_sigma))
    assert not r.gcp_flagged or all(p in block.ground.select("gcp").ids for p in r.gcp_flagged)
    assert "tie" in r.point_role and r.gcp_ids == block.ground.select("gcp").ids


def test_bias_priors_fix_it(block):
    obs = _without_right_gcps(block)
    models = with_bias(block.models, "shift")
    r = adjust(models, obs, block.ground, prior_sigma=bias_prior_sigma(models, 20.0, None))
    assert r.converged and np.all(np.isfinite(r.param_sigma))
    assert r.report.rms_m[0] < 1.0  # planimetry still held by the ties and the left image


def test_one_gcp_and_ties_determine_the_shift(block):
    obs = _without_right_gcps(block, keep=("P00",))
    r = adjust(block.models, obs, block.ground, bias="shift")
    assert r.converged and np.all(np.isfinite(r.param_sigma))
