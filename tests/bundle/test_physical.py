"""A physical multi-image model plugs into the engine unchanged: the UCL Kepler sequence of
002_0f5a34c3ba5aae9c.txt (one orbit shared by fore and aft), given under a tuple of names."""

import equinox as eqx
import jax
import numpy as np
import pytest

from jaxgeo.bundle import AdjustmentError, AdjustSettings, adjust
from jaxgeo.io import GroundPoints, Observations, read_metadata
from jaxgeo.lsq import SolverConfig
from jaxgeo.models import KeplerSequence
from tests.conftest import REPO

N = 16


@pytest.fixture(scope="module")
def kepler():
    scenes = read_metadata(REPO / "tests" / "io" / "data" / "cartosat1_stereo_meta.json")
    truth = KeplerSequence.from_metadata(scenes[:2])
    rng = np.random.default_rng(0)
    ref = np.asarray(truth.image(0).reference_ground())
    g = ref + np.c_[rng.uniform(-0.1, 0.1, N), rng.uniform(-0.1, 0.1, N), rng.uniform(0, 800, N)]
    xy = np.concatenate([np.asarray(truth.image(i).project(g)) for i in range(2)])
    ids = tuple(f"K{i:02d}" for i in range(N))
    role = tuple("gcp" if i < 6 else "check" for i in range(N))
    ground = GroundPoints(ids, g, role, np.full((N, 3), 0.3))
    obs = Observations(
        ids * 2,
        ("fore",) * N + ("aft",) * N,
        xy + rng.normal(0, 0.3, xy.shape),
        np.full(2 * N, 0.3),
    )
    # the start: every attitude angle 2e-5 rad off (several pixels)
    start = eqx.tree_at(lambda s: s.attitude, truth, tuple(a + 2e-5 for a in truth.attitude))
    return truth, start, ground, obs


def test_shared_orbit_model_is_adjusted_as_one_block(kepler):
    truth, start, ground, obs = kepler
    spec = jax.tree.map(lambda _: False, start)
    spec = eqx.tree_at(lambda s: s.attitude, spec, tuple(True for _ in start.attitude))
    # plain least squares: the step count below is the LM's (the default robust loss adds its
    # reweighting passes on top, ~2-5x the steps on clean data)
    l2 = SolverConfig(loss="l2")
    res = adjust({("fore", "aft"): start}, obs, ground, settings=AdjustSettings(filters=spec),
                 solver=l2)  # fmt: skip
    assert res.converged and res.num_steps <= 10
    assert res.param_names[0] == "(fore, aft).attitude[0][0]" and len(res.params) == 6
    true = np.concatenate([np.asarray(a) for a in truth.attitude])
    assert np.abs((res.params - true) / res.param_sigma).max() < 4.0
    assert set(res.models) == {"fore", "aft"}  # image views of the adjusted sequence
    rep = res.report
    for name in ("fore", "aft"):
        assert max(rep.images[name][:2]) < 0.6
    assert 0.6 < res.s0 < 1.4


def test_views_of_one_sequence_given_separately_are_refused(kepler):
    _, start, ground, obs = kepler
    with pytest.raises(AdjustmentError, match=r"share adjustable parameters .* tuple of image"):
        adjust({"fore": start.image(0), "aft": start.image(1)}, obs, ground)
