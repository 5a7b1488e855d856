"""Every way an adjustment can be wrong raises (or warns) with the image/point/parameter named."""

import dataclasses
import warnings

import numpy as np
import pytest

from jaxgeo import Biased, ShiftBias
from jaxgeo.bundle import (
    AdjustmentError,
    AdjustSettings,
    NotConvergedWarning,
    SingularNormalEquations,
    TooFewControlPoints,
    adjust,
)
from jaxgeo.io import GroundPoints, Observations
from jaxgeo.lsq import RESULTS, SolverConfig
from jaxgeo.models import Affine3D
from tests.bundle.conftest import make_block

CHECK, NO_CHECK = AdjustSettings(check_control=True), AdjustSettings(check_control=False)


@pytest.fixture(scope="module")
def small(ventoux_pair):
    return make_block(*ventoux_pair, n=8, n_gcp=4, seed=5)


def _gcps(block, n):
    """The block with only the first ``n`` GCPs kept as GCPs (the rest become check points)."""
    gcps = [p for p, r in zip(block.ground.ids, block.ground.role, strict=True) if r == "gcp"]
    return block.ground.with_roles({p: "check" for p in gcps[n:]})


def _add_obs(obs, pid, image, xy):
    return Observations(
        obs.point_ids + (pid,),
        obs.images + (image,),
        np.vstack([obs.xy, xy]),
        np.append(obs.sigma_px, 0.3),
    )


def test_too_few_gcps_for_the_bias(small):
    # the per-image count rule is opt-in (check=True): by default ties may control an image,
    # and what stays open is reported as undetermined (next assertion)
    with pytest.raises(TooFewControlPoints, match=r"image 'left': the AffineBias .* at least 3"):
        adjust(small.models, small.obs, _gcps(small, 2), bias="affine", settings=CHECK)
    with pytest.raises(TooFewControlPoints, match=r"ShiftDriftBias .* at least 2 .* got 1"):
        adjust(small.models, small.obs, _gcps(small, 1), bias="shift-drift", settings=CHECK)
    with pytest.raises(TooFewControlPoints, match=r"ShiftBias .* at least 1 .* got 0"):
        adjust(small.models, small.obs, _gcps(small, 0), bias="shift", settings=CHECK)
    with pytest.raises(SingularNormalEquations, match=r"bias\.shift_px"):
        adjust(small.models, small.obs, _gcps(small, 0), bias="shift")


def test_3d_affine_needs_four_non_coplanar_gcps(small):
    g = small.ground.lonlath
    flat = g.copy()
    flat[:, 2] = 500.0  # all points at one height: coplanar
    models = {}
    for name, model in small.truth.items():
        xy = np.asarray(model.project(g))
        models[name] = Affine3D.fit(g, xy, space="utm")
    ground = dataclasses.replace(small.ground, lonlath=flat)
    with pytest.raises(TooFewControlPoints, match=r"\(near-\)coplanar"):
        adjust(models, small.obs, ground, settings=CHECK)
    with pytest.raises(TooFewControlPoints, match=r"3D affine .* at least 4 .* got 3"):
        adjust(models, small.obs, _gcps(small, 3), settings=CHECK)


def test_unknown_image_point_seen_once_and_nans(small):
    obs = _add_obs(small.obs, "P03", "middle", [[10.0, 20.0]])
    with pytest.raises(AdjustmentError, match=r"point 'P03' names unknown image 'middle'"):
        adjust(small.models, obs, small.ground, bias="shift")
    obs = _add_obs(small.obs, "T1", "left", [[100.0, 200.0]])
    with pytest.raises(AdjustmentError, match=r"'T1' are seen in one image only .* 'left'"):
        adjust(small.models, obs, small.ground, bias="shift")
    xy = small.obs.xy.copy()
    xy[3, 1] = np.nan
    obs = dataclasses.replace(small.obs, xy=xy)
    with pytest.raises(AdjustmentError, match=r"point 'P03' in image 'left' has a non-finite"):
        adjust(small.models, obs, small.ground, bias="shift")
    lonlath = small.ground.lonlath.copy()
    lonlath[1, 0] = np.inf
    with pytest.raises(AdjustmentError, match=r"ground point 'P01' has non-finite"):
        adjust(small.models, small.obs, dataclasses.replace(small.ground, lonlath=lonlath))


def test_shared_parameters_must_be_one_model(small):
    bias = ShiftBias([1.0, 2.0])
    models = {name: Biased(m, bias) for name, m in small.models.items()}
    with pytest.raises(AdjustmentError, match=r"'left' and 'right' share adjustable parameters"):
        adjust(models, small.obs, small.ground)


def test_singular_normal_equations_name_the_parameters(small):
    # no ground control at all: a common shift of both images is not determined
    no_control = GroundPoints((), np.zeros((0, 3)), (), np.zeros((0, 3)))
    with pytest.raises(SingularNormalEquations, match=r"left\.bias\.shift_px") as err:
        adjust(small.models, small.obs, no_control, bias="shift", settings=NO_CHECK)
    assert set(err.value.parameters) >= {"left.bias.shift_px[0]", "right.bias.shift_px[0]"}


def test_throw_false_returns_the_failure_as_data(small):
    # optimistix' convention: throw=False neither raises nor warns; the result says what failed
    no_control = GroundPoints((), np.zeros((0, 3)), (), np.zeros((0, 3)))
    res = adjust(small.models, small.obs, no_control, bias="shift", throw=False)
    assert not res.converged and bool(res.result == RESULTS.undetermined)
    assert "left.bias.shift_px" in res.message and "not determined" in res.message
    solver = SolverConfig(loss="l2", max_steps=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", NotConvergedWarning)  # no warning with throw=False
        res = adjust(
            small.models, small.obs, small.ground, bias="shift", solver=solver, throw=False
        )
    assert not res.converged and "maximum number of steps" in res.message


def test_no_convergence_warns_and_returns_the_last_state(small):
    # least squares takes 3 steps here (the robust default's inner solves, to 0.1 sigma, 2 each)
    solver = SolverConfig(loss="l2", max_steps=2)
    with pytest.warns(NotConvergedWarning, match=r"did not converge \(maximum number of steps"):
        res = adjust(small.models, small.obs, small.ground, bias="shift", solver=solver)
    assert not res.converged and res.num_steps == 2
    assert np.all(np.isfinite(res.ground)) and np.isfinite(res.cost)
    assert "maximum number of steps" in res.message


def test_undetermined_unknowns_found_in_the_least_squares_equations(small, monkeypatch):
    """Which unknowns a robust solve left undetermined is read from the least-squares normal
    equations at its last point: determinedness is the geometry's, and a robust loss's weights
    at a point the solve drifted to along the null space hid it (the 200 000-observation pair
    without GCPs in one image, Cauchy, XLA's legacy emitters: 100 steps, the aft bias 132 px
    off, no null space found under the Cauchy weights, and every ground point named instead)."""
    from jaxgeo.bundle import _result

    asked = []
    real = _result.undetermined

    def spy(*args, **kwargs):
        asked.append(kwargs.get("loss"))
        return real(*args, **kwargs)

    monkeypatch.setattr(_result, "undetermined", spy)

    def points_only(problem, q, inflation_params, inflation_points):  # as in that case
        return np.zeros(np.shape(inflation_params), bool), np.ones(len(inflation_points), bool)

    monkeypatch.setattr(_result, "undetermined_unknowns", points_only)
    no_control = GroundPoints((), np.zeros((0, 3)), (), np.zeros((0, 3)))
    solver = SolverConfig(loss="cauchy")
    with pytest.raises(SingularNormalEquations):
        adjust(small.models, small.obs, no_control, bias="shift", solver=solver, settings=NO_CHECK)
    assert asked == ["l2"]  # asked although the inflations were finite, and without Cauchy
