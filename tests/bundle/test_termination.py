"""Termination at the floating-point floor: a decrement that rounding keeps above ``tol**2``.

At 320 sub-scenes the squared Newton decrement of the strip's level 1 settles at ~3e-12 (the
Cholesky of the 1920 x 1920 reduced system rounds), above ``tol**2 = 1e-12``, while every tiny
step is accepted: the solve ran to ``max_steps``. Here the same situation is made on a small
block by asking for an unreachable precision (``tol = 0`` and no relative floor): only the
stagnation rule can end the solve, and it must end it at the same solution.
"""

import warnings

import jax
import pytest

from jaxgeo.bundle import NotConvergedWarning, adjust
from jaxgeo.lsq import SolverConfig
from jaxgeo.lsq import _lm as lm
from tests.bundle.conftest import make_block


@pytest.fixture(scope="module")
def small(ventoux_pair):
    return make_block(*ventoux_pair, n=8, n_gcp=4, seed=5)


L2 = SolverConfig(loss="l2")
"""Least squares: one Levenberg-Marquardt solve, whose termination is what is tested here (the
robust default runs several, each ending by the same rule, and compiles twice as long)."""


def _adjust_at_the_floor(small, monkeypatch, stagnant_steps):
    monkeypatch.setattr(lm, "CONVERGED_FLOOR", 0.0)
    monkeypatch.setattr(lm, "STAGNANT_STEPS", stagnant_steps)
    jax.clear_caches()  # the constants are read when the solve is traced
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = adjust(
            small.models,
            small.obs,
            small.ground,
            bias="affine",
            solver=SolverConfig(tol=0.0, max_steps=40, loss="l2"),
        )
    jax.clear_caches()
    return res, [w for w in caught if issubclass(w.category, NotConvergedWarning)]


def test_stagnant_decrement_ends_the_solve(small, monkeypatch):
    ref = adjust(small.models, small.obs, small.ground, bias="affine", solver=L2)
    assert ref.converged
    res, warned = _adjust_at_the_floor(small, monkeypatch, lm.STAGNANT_STEPS)
    assert res.converged and not warned
    assert res.num_steps < 40
    for name in small.models:
        got, want = res.parameters(name), ref.parameters(name)
        for key, (value, sigma) in want.items():
            assert abs(got[key][0] - value) <= 1e-6 * sigma, (name, key)


def test_without_the_rule_the_solve_runs_to_max_steps(small, monkeypatch):
    """The control: the same request with the stagnation rule off never terminates."""
    res, warned = _adjust_at_the_floor(small, monkeypatch, 10**6)
    assert not res.converged and warned
    assert res.num_steps == 40


@pytest.mark.parametrize("negligible", [-1.0, float("inf")])
def test_reused_undamped_step_reaches_the_same_solution(small, monkeypatch, negligible):
    """``step`` reuses the query's undamped Gauss-Newton step once the damping is negligible
    (one factorisation per step). Never reusing it (a second, damped factorisation every step)
    and always reusing it (Gauss-Newton steps judged by the trust region) give the same
    solution as the default."""
    ref = adjust(small.models, small.obs, small.ground, bias="affine", solver=L2)
    monkeypatch.setattr(lm, "NEGLIGIBLE_DAMPING", negligible)
    jax.clear_caches()  # the constant is read when the solve is traced
    res = adjust(small.models, small.obs, small.ground, bias="affine", solver=L2)
    jax.clear_caches()
    assert ref.converged and res.converged
    for name in small.models:
        got, want = res.parameters(name), ref.parameters(name)
        for key, (value, sigma) in want.items():
            assert abs(got[key][0] - value) <= 1e-6 * sigma, (name, key)


def test_extrapolated_last_step_gives_the_same_answer_earlier(small, monkeypatch):
    """Once the decrement contracts fast enough (``lm.CONTRACTION``), the pending undamped
    step is the answer without its evaluation: the same parameters as the solve that evaluates
    it (robust default: its final phase converges quadratically), in fewer steps."""
    fast = adjust(small.models, small.obs, small.ground, bias="affine")
    monkeypatch.setattr(lm, "CONTRACTION", 0.0)  # never extrapolate
    jax.clear_caches()  # the constant is read when the solve is traced
    slow = adjust(small.models, small.obs, small.ground, bias="affine")
    jax.clear_caches()
    assert fast.converged and slow.converged
    assert fast.num_steps < slow.num_steps
    for name in small.models:
        got, want = fast.parameters(name), slow.parameters(name)
        for key, (value, sigma) in want.items():
            assert abs(got[key][0] - value) <= 1e-6 * sigma, (name, key)
