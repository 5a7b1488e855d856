"""Blunders: flagged by standardised residuals, down-weighted by a robust loss."""

import dataclasses

import numpy as np

from jaxgeo.bundle import SolverConfig, adjust
from tests.bundle.conftest import TRUE_BIAS


def _true_params():
    return np.concatenate(
        [
            np.concatenate([np.ravel(TRUE_BIAS[n].shift_px), np.ravel(TRUE_BIAS[n].matrix)])
            for n in ("left", "right")
        ]
    )


def test_blunder_on_a_gcp_is_flagged_and_huber_resists_it(block):
    xy = block.obs.xy.copy()
    bad = 2  # P02 (a GCP) in the left image
    xy[bad, 0] += 12.0
    obs = dataclasses.replace(block.obs, xy=xy)
    plain = SolverConfig(loss="l2", remove_blunders=False)
    # (s0 ~5 with the blunder; it is flagged, so no PoorFitWarning: tests make it an error)
    l2 = adjust(block.models, obs, block.ground, bias="affine", solver=plain)
    huber = adjust(
        block.models,
        obs,
        block.ground,
        bias="affine",
        solver=SolverConfig(loss="huber", loss_scale=2.0, remove_blunders=False),
    )
    clean = adjust(block.models, block.obs, block.ground, bias="affine", solver=plain)
    # w-test: the blunder has by far the largest standardised residual and is flagged
    w = np.abs(l2.standardized).max(axis=1)
    assert int(np.argmax(w)) == bad and l2.blunders[bad] and w[bad] > 10.0
    # (with 6 GCPs for 6 affine parameters the blunder leaks into a few other GCP residuals)
    assert l2.blunders.sum() <= 6 and not clean.blunders.any()
    assert huber.converged and clean.converged
    # the plain residual of the blunder is reported in pixels (not robust-scaled)
    assert abs(huber.residuals_px[bad, 0]) > 8.0
    # l2 is pulled away from the truth; Huber stays close to the blunder-free solution
    truth = _true_params()
    err = {
        k: np.abs((r.params - truth) / clean.param_sigma).max()
        for k, r in (("l2", l2), ("huber", huber), ("clean", clean))
    }
    assert err["l2"] > 2 * err["huber"]
    assert err["huber"] < err["clean"] + 1.5
