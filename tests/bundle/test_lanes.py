"""The batch queue (``solve_batch``: lanes that take the next problem once theirs terminates)
gives each problem what its own solve gives: same unknowns, result, steps and weights."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo.bundle import with_bias
from jaxgeo.bundle._prepare import prepare
from jaxgeo.lsq import RESULTS, SolverConfig, solve, solve_batch
from jaxgeo.lsq import _batch as batch_module
from jaxgeo.lsq._batch import with_xy_batch
from tests.bundle.conftest import make_block


@pytest.fixture(scope="module")
def batch(ventoux_pair):
    """Eleven noisy copies of a shift-bias pair: clean ones, some with a gross error (more
    reweighting steps: stragglers), one with a non-finite measurement (fails at once)."""
    small = make_block(*ventoux_pair, n=8, n_gcp=4, seed=5)
    problem = prepare(with_bias(small.models, "shift"), small.obs, small.ground).problem
    xy0 = np.concatenate([np.asarray(ob.xy) for ob in problem.images])
    rng = np.random.default_rng(3)
    xy = xy0 + rng.normal(0.0, 0.3, (11, *xy0.shape))
    for k, size in ((2, 40.0), (5, 15.0), (6, 80.0), (9, 25.0)):
        xy[k, 3 * k % xy0.shape[0]] += size
    xy[7, 1, 0] = np.nan
    return problem, xy


@pytest.mark.parametrize("loss", ["cauchy", "l2"])
def test_queue_gives_each_problem_its_own_solution(batch, loss):
    problem, xy = batch
    solver = SolverConfig(loss=loss)
    # three lanes for eleven problems: lanes are refilled many times, out of order
    got = solve_batch(with_xy_batch(problem, xy), solver, chunk=3)
    one = eqx.filter_jit(lambda p: solve(p, solver))
    steps = []
    for k in range(xy.shape[0]):
        want = one(problem.with_xy(jnp.asarray(xy[k])))
        assert int(got.result._value[k]) == int(want.result._value), k
        assert int(got.num_steps[k]) == int(want.num_steps), k
        steps.append(int(want.num_steps))
        if not bool(want.result == RESULTS.successful):
            continue
        np.testing.assert_allclose(got.theta[0][k], want.theta[0], rtol=1e-9, atol=1e-10)
        # lon, lat (deg) to 1e-12 relative (~5e-6 m); heights to 10 nm: the batched and the single
        # program round differently (one CI run: 0.66 nm apart on a 459 m height; jaxlib 0.11.2
        # on a CPU: 1.46 nm on 1097 m, 1.3e-12 of it)
        np.testing.assert_allclose(got.ground[k][:, :2], want.ground[:, :2], rtol=1e-12)
        np.testing.assert_allclose(got.ground[k][:, 2], want.ground[:, 2], rtol=0, atol=1e-8)
        np.testing.assert_allclose(got.weight_image[k], want.weight_image, atol=1e-9)
        np.testing.assert_allclose(got.s0[k], want.s0, rtol=1e-9)
    codes = np.asarray(got.result._value)
    # the non-finite measurement is reported as such, by the single solve and the queue alike
    # (it was "successful" with the parameters left at their start, or "undetermined")
    assert codes[7] == RESULTS.nonfinite._value
    assert np.sum(codes == RESULTS.successful._value) == 10
    if loss == "cauchy":  # the gross errors make stragglers: the lanes do not finish together
        assert len(set(steps)) > 2


def test_chunks_are_balanced_and_capped_by_problem_size(batch, monkeypatch):
    assert batch_module.balanced_chunk(10_000, 1, 1024) == 1000
    assert batch_module.balanced_chunk(1500, 1, 1024) == 750
    assert batch_module.balanced_chunk(11, 1, 3) == 3
    assert batch_module.balanced_chunk(4, 4, 1024) == 1
    assert batch_module.balanced_chunk(0, 1, 1024) == 1  # no problems: no division by zero
    assert batch_module.balanced_chunk(10, 1, 0) == 1
    for n in (1, 7, 1025, 4097, 10_001):
        for devices in (1, 4):
            for cap in (1, 5, 512, 1024):
                c = batch_module.balanced_chunk(n, devices, cap)
                chunks = -(-n // (c * devices))
                assert 1 <= c <= cap
                assert chunks * c * devices - n < chunks * devices  # < one padded per chunk
    problem, xy = batch
    stacked = with_xy_batch(problem, xy)
    assert batch_module.default_chunk(stacked) == batch_module.DEFAULT_CHUNK
    monkeypatch.setattr(batch_module, "LANE_ELEMENTS", 1000)  # large problems: fewer lanes
    assert 1 <= batch_module.default_chunk(stacked) < 1000 // 100
