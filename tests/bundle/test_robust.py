"""Blunders: flagged by standardised residuals, down-weighted by a robust loss."""

import dataclasses

import numpy as np
import pytest

from jaxgeo.bundle import PoorFitWarning, adjust
from jaxgeo.lsq import SolverConfig
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


def test_robust_answer_does_not_depend_on_where_the_reweighting_stops(block):
    # the reweighting only brings the solve near the M-estimate; the last (robust, Newton)
    # solve goes to it, to the solver's tolerance, however loose irls_tol is
    xy = block.obs.xy.copy()
    xy[2, 0] += 12.0  # a blunder on a GCP, and one on another observation
    xy[7, 1] -= 9.0
    obs = dataclasses.replace(block.obs, xy=xy)
    runs = {
        tol: adjust(
            block.models,
            obs,
            block.ground,
            bias="affine",
            solver=SolverConfig(irls_tol=tol, remove_blunders=False),
        )
        for tol in (0.2, 1e-2, 1e-3)
    }
    ref = runs[1e-3]  # the former default
    assert all(r.converged for r in runs.values())
    for tol in (0.2, 1e-2):
        assert np.max(np.abs((runs[tol].params - ref.params) / ref.param_sigma)) < 1e-5
        np.testing.assert_allclose(runs[tol].s0, ref.s0, rtol=1e-7)
    # and the robust loss did act: the blunders move the least-squares answer far more
    with pytest.warns(PoorFitWarning):  # s0 ~3 with the blunders kept
        l2 = adjust(
            block.models,
            obs,
            block.ground,
            bias="affine",
            solver=SolverConfig(loss="l2", remove_blunders=False),
        )
    assert np.max(np.abs((l2.params - ref.params) / ref.param_sigma)) > 100 * 1e-5
