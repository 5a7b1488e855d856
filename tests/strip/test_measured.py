"""Tie points measured by the user enter level 1; check points with a gross error of their own
are named and left out of the statistics (issue 11: nothing in ``observations.csv`` ignored)."""

import dataclasses

import numpy as np
import pytest

from jaxgeo.io import Observations
from jaxgeo.strip import MeasuredTieWarning, adjust_strip
from jaxgeo.strip._level1 import level1_input
from jaxgeo.strip._snooping import gross_checks
from jaxgeo.strip._ties import strip_ties
from tests.strip.conftest import TIES, strip_config

GSD_M = 0.65  # Carto-2S, as test_solve


def _with_measured(strip, per_pair=4, seed=3):
    """``strip`` plus measured ties ``M0000...`` (strip pixels seen in two adjacent sub-scenes,
    as a matcher would return them) and the ids."""
    t = strip_ties(strip.scenes, per_pair, margin_px=50.0, seed=seed)
    o = strip.observations
    ids = tuple(f"M{p:04d}" for p in t.point)
    sigma = np.full(len(ids), float(np.median(o.sigma_px)))
    obs = Observations(
        o.point_ids + ids,
        o.images + tuple(strip.names[k] for k in t.scene),
        np.concatenate([o.xy, t.xy]),
        np.concatenate([o.sigma_px, sigma]),
    )
    return dataclasses.replace(strip, observations=obs), sorted(set(ids))


def test_measured_ties_enter_level1_and_one_view_points_are_named(strip_quarter):
    strip, ids = _with_measured(strip_quarter)
    inp = level1_input(strip)
    assert inp.measured_ids == tuple(ids)
    n_formed = len(inp.ties.point)
    seen = inp.observations.point_ids
    assert set(seen[n_formed:]) >= set(ids)  # after the formed ties and the GCP rows
    assert inp.ground.ids[-len(ids) :] == tuple(ids)  # with a height prior each
    assert np.all(np.isinf(inp.ground.sigma_m[-len(ids) :, :2]))
    # a point measured in one sub-scene only: named, left out
    o = strip.observations
    one = Observations(
        o.point_ids + ("LONE",), o.images + (strip.names[0],),
        np.concatenate([o.xy, [[100.0, 100.0]]]), np.concatenate([o.sigma_px, [0.3]]),
    )  # fmt: skip
    with pytest.warns(MeasuredTieWarning, match="one sub-scene only.*'LONE'"):
        inp = level1_input(dataclasses.replace(strip, observations=one))
    assert "LONE" not in inp.measured_ids and "LONE" not in inp.observations.point_ids
    # a measured point named like a formed tie: refused, named
    tid = inp.tie_ids[1]
    clash = Observations(
        o.point_ids + (tid, tid), o.images + strip.names[:2],
        np.concatenate([o.xy, [[100.0, 100.0], [100.0, 200.0]]]),
        np.concatenate([o.sigma_px, [0.3, 0.3]]),
    )  # fmt: skip
    with pytest.raises(ValueError, match=f"'{tid}'.*clash with the ids of the formed ties"):
        level1_input(dataclasses.replace(strip, observations=clash))


@pytest.mark.filterwarnings("ignore::jaxgeo.strip._errors.UniversalCorrectionWarning")
def test_measured_tie_and_check_gross_errors_named(strip_quarter):
    """One measured tie ray moved by 40 px: flagged at level 1 (the measured tie is in the
    adjustment); one check measurement moved by 30 px: named as a gross check and out of the
    statistics, which keep the clean strip's accuracy."""
    strip, ids = _with_measured(strip_quarter)
    o = strip.observations
    xy = o.xy.copy()
    tie_row = o.point_ids.index(ids[5])
    xy[tie_row] += [40.0, 0.0]
    role = dict(zip(strip.ground.ids, strip.ground.role, strict=True))
    check_rows = [i for i, p in enumerate(o.point_ids) if role.get(p) == "check"]
    bad_check = check_rows[len(check_rows) // 2]
    xy[bad_check] += [0.0, 30.0]
    strip = dataclasses.replace(
        strip, observations=Observations(o.point_ids, o.images, xy, o.sigma_px)
    )
    res = adjust_strip(strip, strip_config())
    rep = res.report.strip
    print(res.report.format())
    assert rep["n_measured_ties"] == len(ids) and rep["n_ties"] > TIES
    assert set(ids) <= set(res.level1.observation_ids)
    flagged = {(f["id"], f["level"]) for f in res.gross_errors.flagged}
    assert (ids[5], 1) in flagged
    gross = res.gross_errors.checks_gross
    assert [c["id"] for c in gross] == [o.point_ids[bad_check]]
    assert abs(gross[0]["n_m"]) > 10.0  # 30 px of ~0.65 m, north-ish
    assert rep["n_check_excluded"] >= 1
    assert rep["check_rms_m"]["level2"]["plan"] < 1.5 * GSD_M
    assert "gross error of their own" in res.report.format()


def test_gross_checks_name_the_outlier_never_a_model_error():
    """Errors growing along the strip (extrapolation away from the GCP scenes) and a sub-scene
    whose checks are all 40 m off (a wrong line offset: the model's error) are no gross checks;
    one check 8 m off the others of its sub-scene is; sub-scenes with fewer than 3 checks and
    fewer than 5 checks in all: nothing."""
    rng = np.random.default_rng(0)
    scene = np.repeat(np.arange(20), 6)
    trend = np.stack([0.25 * scene, -0.1 * scene], -1)  # up to 4.75 m east
    err = trend + rng.normal(0.0, 0.4, trend.shape)
    err[scene == 9] += [0.0, 40.0]
    assert not gross_checks(scene, err).any()
    err[37] += [0.0, 8.0]
    assert np.flatnonzero(gross_checks(scene, err)).tolist() == [37]
    two = np.repeat(np.arange(60), 2)  # two checks per sub-scene: none can be judged
    assert not gross_checks(two, err).any()
    assert not gross_checks(scene[:4], err[:4] + [[50.0, 0.0], [0, 0], [0, 0], [0, 0]]).any()
