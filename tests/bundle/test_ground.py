"""Ground-control residuals without trigonometry per evaluation (``bundle/ground.py``) equal the
plain geodetic -> ENU formula; points beyond the exact range are reported."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo import geodesy
from jaxgeo.bundle import with_bias
from jaxgeo.bundle._prepare import prepare
from jaxgeo.lsq import RESULTS, SolverConfig, solve
from jaxgeo.lsq import _ground as bundle_ground
from tests.bundle.conftest import make_block


@pytest.fixture(scope="module")
def problem(ventoux_pair):
    small = make_block(*ventoux_pair, n=8, n_gcp=4, seed=5)
    return prepare(with_bias(small.models, "shift"), small.obs, small.ground).problem


def test_enu_residuals_equal_the_geodetic_formula(problem):
    rng = np.random.default_rng(0)
    u = jnp.asarray(rng.normal(0.0, 2000.0, problem.origin.shape))  # metres, up to ~8 km
    ground = problem.ground_points(u)
    gobs = problem.ground
    want = jax.vmap(geodesy.geodetic_to_enu)(ground[gobs.point], gobs.lonlath)
    got = bundle_ground.enu_residuals(problem, u, ground)
    framed = bundle_ground.with_frames(problem)
    assert framed.ground.frame is not None and problem.ground.frame is None
    got_framed = bundle_ground.enu_residuals(framed, u, ground)
    # 2e-8 m: the ground points rounded to degrees (the formula's input) against the offsets
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-8)
    np.testing.assert_array_equal(got_framed, got)
    assert not bool(bundle_ground.beyond_offset(problem, u))


def test_points_beyond_the_exact_range_are_reported(problem, monkeypatch):
    pt = int(problem.ground.point[0])
    u = np.zeros(problem.origin.shape)
    u[pt, 1] = np.rad2deg(1.01 * geodesy.OFFSET_MAX_RAD) * float(problem.metres_per_unit[pt, 1])
    assert bool(bundle_ground.beyond_offset(problem, jnp.asarray(u)))
    # wired into the solve's result: with a range of 1e-12 rad every adjusted GCP lies beyond
    ok = solve(problem, SolverConfig(loss="l2"))
    assert bool(ok.result == RESULTS.successful)
    monkeypatch.setattr(geodesy, "OFFSET_MAX_RAD", 1e-12)
    jax.clear_caches()  # the constant is read when the solve is traced
    far = eqx.filter_jit(lambda p: solve(p, SolverConfig(loss="l2")))(problem)
    jax.clear_caches()
    assert bool(far.result == RESULTS.outside_domain)
