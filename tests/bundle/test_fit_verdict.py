"""Snooping's limits and the fit verdict (issue 27): snooping removes at most max(1, 20 %) of the
GCPs, of each image's GCPs and of each image's observations; more "gross errors" than that are
models that do not fit, declared by :class:`PoorFitWarning` (``result.poor_fit``) with the images
named, and the check points are reported with and without the flagged ones. Measurements are
checked against the image's raster when its size is known."""

import dataclasses
import warnings

import numpy as np
import pytest

from jaxgeo.bundle import (
    AdjustmentError,
    AdjustSettings,
    PoorFitWarning,
    adjust,
    prepare,
    with_bias,
)
from jaxgeo.bundle._snooping import over_limits, removal_cap
from jaxgeo.io import read_ground, read_observations, read_rpc
from jaxgeo.simulate import demo_dir


@pytest.fixture(scope="module")
def demo():
    d = demo_dir()
    models = {n: read_rpc(d / f"{n}.txt") for n in ("fore", "aft")}
    return models, read_observations(d / "observations.csv"), read_ground(d / "ground.csv")


def _adjust(*args, **kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = adjust(*args, **kwargs)
    poor = [str(w.message) for w in caught if issubclass(w.category, PoorFitWarning)]
    return result, poor


def test_removal_cap():
    assert [removal_cap(n) for n in (0, 1, 2, 4, 5, 9, 10, 69, 1000)] == [
        0, 0, 1, 1, 1, 1, 2, 13, 200
    ]  # fmt: skip


def test_over_limits_counts_gcps_per_block_and_per_image(demo):
    models, obs, ground = demo
    setup = prepare(with_bias(models, "affine"), obs, ground)
    m, c = len(obs.point_ids), int(setup.problem.ground.point.shape[0])
    gcp_rows = np.array([setup.point_role[setup.point_ids.index(p)] == "gcp"
                         for p in setup.ground_ids])  # fmt: skip
    none_i, none_g = np.zeros(m, bool), np.zeros(c, bool)
    assert over_limits(setup, none_i, none_g) == []
    one = none_g.copy()
    one[np.flatnonzero(gcp_rows)[0]] = True
    assert over_limits(setup, none_i, one) == []  # one GCP of nine
    two = one.copy()
    two[np.flatnonzero(gcp_rows)[1]] = True
    reasons = over_limits(setup, none_i, two)
    assert reasons and reasons[0].startswith("2 of the 9 GCPs")
    # two GCP rays in one image: the GCPs no longer control it
    point = np.asarray(setup.problem.structure.obs_point)
    image = np.asarray(obs.images)[setup.obs_order]  # per problem observation
    gcp_points = np.unique(np.asarray(setup.problem.ground.point)[gcp_rows])
    drop = none_i.copy()
    drop[np.flatnonzero(np.isin(point, gcp_points) & (image == "fore"))[:2]] = True
    reasons = over_limits(setup, drop, none_g)
    assert any("2 of the 9 GCPs of image 'fore'" in r for r in reasons), reasons
    # check points measured in both images removed whole: each counts once, shared
    check = [j for j, r in enumerate(setup.point_role) if r == "check"]
    whole = np.isin(point, check[:26])  # 26 two-ray points: 13 per image, at the limit
    assert over_limits(setup, whole, none_g) == []
    whole = np.isin(point, check[:28])
    assert any("14 of the 69 observations" in r for r in over_limits(setup, whole, none_g))


def test_swapped_models_keep_their_gcps_and_are_declared(demo):
    """Before: six of the nine GCPs removed as gross errors, s0 0.57, no warning."""
    models, obs, ground = demo
    swapped = {"fore": models["aft"], "aft": models["fore"]}
    r, poor = _adjust(swapped, obs, ground, bias="affine")
    assert len(poor) == 1 and r.poor_fit == poor[0]
    assert "'fore'" in poor[0] and "'aft'" in poor[0] and "do not fit" in poor[0]
    assert r.gcp_removed == () and r.removed.sum() <= 0.2 * len(obs.point_ids)
    # the check points are reported, and show the misfit
    assert r.report_all.n == 60 and r.report_all.rms_m[2] > 100.0


def test_bias_none_reports_every_check_point(demo):
    models, obs, ground = demo
    r, poor = _adjust(models, obs, ground, bias="none")
    assert poor and r.poor_fit
    assert r.report.n == 60 - len(r.checks_excluded) < 60
    assert r.report_all.n == 60 and np.all(np.isfinite(r.report_all.rms_m))
    assert r.report_all.rms_m[1] > 30.0  # the vendor RPCs' tens of metres


def test_clean_block_is_not_declared(demo):
    models, obs, ground = demo
    r, poor = _adjust(models, obs, ground, bias="affine")
    assert not poor and r.poor_fit == "" and r.converged
    assert r.report_all is r.report and r.report.n == 60


def test_same_model_for_two_images(demo):
    models, obs, ground = demo
    with pytest.raises(AdjustmentError, match="images 'fore' and 'aft' have the same RPC"):
        adjust({"fore": models["fore"], "aft": models["fore"]}, obs, ground, bias="shift")


def test_measurements_checked_against_the_raster(demo):
    models, obs, ground = demo
    # 6000 x 6000 px raster (its pixels the model's): the measurements beyond x 6000 are named
    box = {"fore": (-0.5, -0.5, 5999.5, 5999.5)}
    beyond = (np.asarray(obs.images) == "fore") & (obs.xy[:, 0] > 6000.0)
    i = int(np.flatnonzero(beyond)[0])  # the first one is named
    named = rf"point {obs.point_ids[i]!r} \(\w+\) at x, y = .* lies \d+ px outside image 'fore' "
    with pytest.raises(AdjustmentError, match=named + r".*its raster, 6000 x 6000 px"):
        prepare(models, obs, ground, settings=AdjustSettings(image_domains=box))
    # without the raster, the RPC's image domain (0..11999 px) accepts them
    prepare(models, obs, ground)
    xy = obs.xy.copy()
    xy[i] = [13000.0, 500.0]
    far = dataclasses.replace(obs, xy=xy)
    with pytest.raises(AdjustmentError, match="from its RPC's image offset"):
        prepare(models, far, ground)
