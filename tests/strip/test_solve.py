"""The two-level full-strip adjustment (003_ sections 6-9) on a simulated Carto-2S strip.

One strip with GCPs surveyed in every sub-scene; the two-level adjustment uses only those of a
quarter of the scenes (every fourth and the last, the rule of section 9), the scene-by-scene
adjustment (the practice of the paper's figure 2 and table 1) uses all of them. Then gross
errors in that strip (robust loss and data snooping at both levels, wrong line offsets), here
and not in a module of their own: the corrupted strips have the clean strip's shapes and reuse
its compiled solves, which are freed after every module (tests/conftest.py).
"""

import dataclasses
import json
import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgeo.strip._adjustment as strip_adjustment
from jaxgeo.io import Observations, read_observations
from jaxgeo.lsq import RESULTS
from jaxgeo.models import project_points
from jaxgeo.simulate._gross import flag_scores
from jaxgeo.strip import (
    GCPDistributionWarning,
    Level1Config,
    LineOffsetWarning,
    StripConfig,
    StripFormatError,
    adjust_individually,
    adjust_strip,
    evaluate_models,
    read_strip,
)
from jaxgeo.strip._batch import monte_carlo_inputs
from jaxgeo.strip._level1 import level1_input
from jaxgeo.strip._report import line_offset_message
from jaxgeo.strip._snooping import suspect_offsets
from jaxgeo.strip._solve import degree_index, two_level_batch, two_level_jit
from tests.strip.conftest import N_SCENES, QUARTER, TIES
from tests.strip.conftest import strip_config as _config

GSD_M = 0.63
NOISE_M = 0.3 * GSD_M  # image noise of the simulated measurements, on the ground


def _rms(x):
    return float(np.sqrt(np.mean(np.asarray(x) ** 2)))


@pytest.fixture(scope="module")
def sim(strip_sim):
    return strip_sim


@pytest.fixture(scope="module")
def full(strip_full):
    return strip_full


@pytest.fixture(scope="module")
def quarter(strip_quarter):
    return strip_quarter


@pytest.fixture(scope="module")
def result(strip_result):
    return strip_result


@pytest.fixture(scope="module")
def individual(full, result):
    models, res = adjust_individually(full)
    assert res is not None and res.converged
    return evaluate_models(result, models)


def test_gcp_quarter(full, quarter, result):
    assert full.gcp_scenes() == list(range(N_SCENES))
    assert quarter.gcp_scenes() == list(QUARTER)
    assert result.distribution.ok
    assert result.level1.converged
    s = result.report.strip
    assert s["scenes"] == N_SCENES and s["n_ties"] == TIES * (N_SCENES - 1)
    assert [r["gcp"] for r in result.report.scenes] == [k in QUARTER for k in range(N_SCENES)]


def test_continuity_after_level1(result):
    """Tie gaps: metres with the vendor RPCs, far below the measurement noise after level 1."""
    gaps = result.report.strip["tie_gap_m"]
    print({k: round(v["rms"], 4) for k, v in gaps.items()})
    assert gaps["direct"]["rms"] > 0.5
    assert gaps["level1"]["rms"] < 0.1 * NOISE_M and gaps["level1"]["max"] < 0.2 * NOISE_M
    assert gaps["level2"]["rms"] < 0.1 * NOISE_M
    for pair in result.report.pairs:
        assert pair["level1"]["max"] < 0.2 * NOISE_M, pair


def test_scene_by_scene_leaves_discontinuities(result, individual):
    """Figure 2: each scene adjusted to its own GCPs leaves gaps between scenes; level 1 not."""
    gap_ind = np.hypot(*individual["tie_gap_m"].T)
    gap_l1 = result.report.strip["tie_gap_m"]["level1"]
    print(f"tie gaps RMS/max: one by one {_rms(gap_ind):.3f}/{gap_ind.max():.3f} m, "
          f"level 1 {gap_l1['rms']:.4f}/{gap_l1['max']:.4f} m")  # fmt: skip
    assert _rms(gap_ind) > 0.2  # visible: about a pixel
    assert _rms(gap_ind) > 20 * gap_l1["rms"]


def test_absolute_accuracy_level2_vs_individual(result, individual):
    """Table 1: with GCPs in a quarter of the scenes, level 2 is as accurate at the check points
    as adjusting every scene to its own GCPs."""
    s = result.report.strip["check_rms_m"]
    ind = _rms(np.hypot(*individual["check_error_m"].T))
    print({k: round(v["plan"], 3) for k, v in s.items()}, f"one by one {ind:.3f} m")
    assert s["direct"]["plan"] > 5.0
    assert s["level2"]["plan"] < 1.25 * ind
    assert s["level2"]["plan"] < 1.5 * GSD_M
    worst = max(r["level2"]["plan"] for r in result.report.scenes)
    assert worst < 3 * GSD_M


def test_auto_degree_picks_the_best_cross_validated(quarter, result, individual):
    res = adjust_strip(quarter, _config("auto"))
    s = res.report.strip
    cv = s["leave_one_scene_out_rms_m"]
    assert cv == pytest.approx(result.report.strip["leave_one_scene_out_rms_m"])
    assert s["degree"] == min(cv, key=cv.get)
    ind = _rms(np.hypot(*individual["check_error_m"].T))
    print(cv, s["degree"], round(s["check_rms_m"]["level2"]["plan"], 3), f"one by one {ind:.3f}")
    assert (
        s["check_rms_m"]["level2"]["plan"] <= result.report.strip["check_rms_m"]["level2"]["plan"]
    )
    assert s["check_rms_m"]["level2"]["plan"] < 1.15 * ind


# with GCPs in only a quarter of the scenes the fixed quadratic predicts worse than the affine
# correction, and the library says so (the warning the "auto" degree exists for)
@pytest.mark.filterwarnings("ignore::jaxgeo.strip._errors.UniversalCorrectionWarning")
def test_ties_only_level1_then_universal_correction(quarter, strip_ties_only):
    """The paper's pure flow: level 1 with ties only (relative), level 2 absolute."""
    with pytest.raises(ValueError, match="bias priors"):
        adjust_strip(quarter, _config(use_gcps=False))
    prior = np.array([50.0, 50.0, 1e-4, 1e-4, 1e-4, 1e-4])
    res = {
        "quadratic": strip_ties_only,
        "auto": adjust_strip(quarter, _config("auto", use_gcps=False, bias_prior_sigma=prior)),
    }
    s = res["quadratic"].report.strip
    print({k: round(v["plan"], 3) for k, v in s["check_rms_m"].items()})
    assert s["tie_gap_m"]["level1"]["rms"] < 0.1 * NOISE_M
    assert s["check_rms_m"]["level1"]["plan"] > 0.5 * s["check_rms_m"]["direct"]["plan"]
    assert s["check_rms_m"]["level2"]["plan"] < 1.5 * GSD_M
    a = res["auto"].report.strip
    print(a["degree"], a["leave_one_scene_out_rms_m"], round(a["check_rms_m"]["level2"]["plan"], 3))
    assert a["degree"] != "none"  # level 1 alone is not absolute: a correction is needed
    assert a["check_rms_m"]["level2"]["plan"] < 1.5 * GSD_M


def test_distribution_rule_warns_before_solving(full):
    bad = full.with_gcp_scenes([0, 11])
    with pytest.warns(GCPDistributionWarning, match=r"scene_001\.\.scene_010"):
        with pytest.raises(ValueError, match="bias priors"):  # raised before any solving
            adjust_strip(bad, StripConfig(level1=Level1Config(use_gcps=False)))


def test_monte_carlo_batch_equals_single_runs(result):
    """Monte-Carlo runs in one jitted call (``lax.map``: a vmapped batch deadlocked in
    jaxlib's batched LAPACK Cholesky, see ``two_level_batch``) == the same runs one by one.
    Least squares: it compiles in half the time of the robust default."""
    xy, gcp_xy, check_xy = monte_carlo_inputs(result, 3, seed=2)
    c = result.config
    args = (degree_index(c.level2.degree), dataclasses.replace(c.solver, loss="l2"))
    problem, data = result.setup.problem, result.data
    sols, evs = two_level_batch(problem, data, xy, gcp_xy, check_xy, *args)
    assert sols.level1.theta[0].shape == (3, N_SCENES, 6)
    assert np.all(np.asarray(sols.level1.result == RESULTS.successful))
    for k in (0, 2):
        d = eqx.tree_at(lambda t: (t.gcp_xy, t.check_xy), data, (gcp_xy[k], check_xy[k]))
        one = two_level_jit(problem.with_xy(jnp.asarray(xy[k])), d, *args)
        dt = np.abs(np.asarray(sols.level1.theta[0][k]) - np.asarray(one.level1.theta[0]))
        assert dt.max() < 1e-8
        dc = np.abs(np.asarray(sols.correction.coeffs[k]) - np.asarray(one.correction.coeffs))
        assert dc.max() < 1e-12
    # the noise moves the solution: runs differ from each other
    assert np.ptp(np.asarray(sols.level1.theta[0])[:, :, 0], axis=0).max() > 1e-3
    rms = [_rms(np.hypot(*np.asarray(e).T)) for e in evs.check_error_level2_m]
    assert max(rms) < 2 * GSD_M


def test_updated_rpcs_reproduce_final_models(result, quarter):
    names = quarter.names[:2]
    fits = result.updated_rpcs(names=names)
    o = quarter.observations
    g = {p: x for p, x in zip(quarter.ground.ids, quarter.ground.lonlath, strict=True)}
    for name in names:
        rpc, rep = fits[name]
        assert rep.check_rms_px < 1e-3
        rows = [i for i, img in enumerate(o.images) if img == name]
        ground = np.array([g[o.point_ids[i]] for i in rows])
        want = project_points(result.models[name], ground)
        got = project_points(rpc, ground)
        assert np.abs(got - want).max() < 0.01


def test_read_strip_round_trip_and_errors(sim, tmp_path):
    sim.save(tmp_path)
    strip = read_strip(tmp_path)
    assert strip.names == sim.names
    assert [s.line_offset for s in strip.scenes] == list(sim.first_rows)
    g = np.array([[float(sim.vendor[sim.names[3]].ground_offset[i]) for i in range(3)]])
    assert np.allclose(project_points(strip.rpcs[sim.names[3]], g),
                       project_points(sim.vendor[sim.names[3]], g), atol=1e-6)  # fmt: skip
    desc = json.loads((tmp_path / "strip.json").read_text())
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"scenes": desc["scenes"][::-1]}))
    with pytest.raises(StripFormatError, match="strip order"):
        read_strip(bad)
    del desc["scenes"][2]["first_line"]
    bad.write_text(json.dumps(desc))
    with pytest.raises(StripFormatError, match=r"bad\.json.*scene_002.*first_line"):
        read_strip(bad)
    bad.write_text("{not json")
    with pytest.raises(StripFormatError, match=r"bad\.json:1"):
        read_strip(bad)
    obs = read_observations(tmp_path / "observations.csv")
    assert len(obs) == len(strip.observations)
    desc = json.loads((tmp_path / "strip.json").read_text())
    desc["scenes"] = desc["scenes"][:3]  # observations now name sub-scenes not in the strip
    bad.write_text(json.dumps(desc))
    with pytest.raises(StripFormatError, match="not sub-scenes of the strip"):
        read_strip(bad)


# --- gross errors: robust loss and data snooping at both levels, wrong line offsets --------------
#
# The strip of conftest (12 sub-scenes, GCPs in a quarter of them) with 10 % of its GCP image
# measurements and 10 % of its formed ties (one ray each) moved by 10-100 px in a random direction;
# with the default settings the check points must stay as accurate as on the clean strip and the
# gross errors must be named. A formed tie has two rays that agree with each other only: the
# snooping removes the tie (both rays), so ties are scored per tie point, GCP measurements per
# (point, sub-scene).

FRACTION = 0.1
PRIOR = np.array([50.0, 50.0, 1e-4, 1e-4, 1e-4, 1e-4])  # ties-only level 1: weak bias priors
_GROSS = pytest.mark.filterwarnings(
    "ignore::jaxgeo.strip._errors.UniversalCorrectionWarning"  # 4 GCP scenes: see above
)


def _errors(rng, n):
    """``n`` gross errors (px): 10-100 px in a random direction."""
    angle, size = rng.uniform(0.0, 2 * np.pi, n), rng.uniform(10.0, 100.0, n)
    return np.stack([np.cos(angle), np.sin(angle)], -1) * size[:, None]


def _corrupt_gcps(strip, rng):
    """The strip with ``FRACTION`` of its GCP measurements moved; the set ``{(id, image)}``."""
    o = strip.observations
    role = dict(zip(strip.ground.ids, strip.ground.role, strict=True))
    rows = [i for i, p in enumerate(o.point_ids) if role[p] == "gcp"]
    pick = rng.choice(rows, max(2, round(FRACTION * len(rows))), replace=False)
    xy = o.xy.copy()
    xy[pick] += _errors(rng, len(pick))
    bad = {(o.point_ids[i], o.images[i]) for i in pick}
    return dataclasses.replace(
        strip, observations=Observations(o.point_ids, o.images, xy, o.sigma_px)
    ), bad


def _corrupting_ties(rng, bad: set):
    """A ``level1_input`` that moves one ray of ``FRACTION`` of the formed ties (into ``bad``)."""

    def corrupted(strip, config=None, use_gcps=True):
        inp = level1_input(strip, config, use_gcps)
        t = inp.ties
        chosen = rng.choice(t.n_ties, round(FRACTION * t.n_ties), replace=False)
        rows = [np.flatnonzero(t.point == p)[rng.integers(2)] for p in chosen]
        o = inp.observations
        xy = np.array(o.xy)
        xy[rows] += _errors(rng, len(rows))
        bad.update(inp.tie_ids[p] for p in chosen)
        obs = Observations(o.point_ids, o.images, xy, o.sigma_px)
        return dataclasses.replace(inp, observations=obs)

    return corrupted


def _scores(result, bad_obs: set, bad_ties: set) -> tuple[float, float, int]:
    """Recall, precision and count of the flags (:func:`jaxgeo.simulate._gross.flag_scores`)."""
    return tuple(flag_scores(result.gross_errors.flagged, bad_obs, bad_ties))


def _plan(result, stage="level2"):
    return result.report.strip["check_rms_m"][stage]["plan"]


@_GROSS
def test_clean_strip_flags_nothing_and_keeps_least_squares(strip_result):
    """Clean data: (almost) nothing flagged, the Cauchy weights all near 1 (the solution is that
    of least squares to a fraction of sigma), the accuracy of the paper's flow."""
    res = strip_result
    g = res.gross_errors
    n_obs = len(res.level1.observation_ids) + len(res.data.gcp_xy)
    print(g.format(), f"check RMS {_plan(res):.3f} m")
    assert g.loss == "cauchy" and len(g.flagged) <= 0.01 * n_obs
    assert g.line_offsets == [] and res.report.strip["n_check_excluded"] == 0
    w = np.asarray(res.solution.level1.weight_image)
    assert w.min() > 0.85 and np.median(w) > 0.97
    assert _plan(res) < 1.5 * GSD_M
    assert res.report.strip["gross_errors"]["n_removed"] == len(g.flagged) == g.n_removed


SEEDS = (11, 12, 13)


@_GROSS
def test_level1_gross_errors_flagged_and_removed(strip_quarter, strip_result, monkeypatch):
    """Three draws of gross errors (10 % of the GCP measurements and of the ties each): every
    draw as accurate as the clean strip, the flags scored over all draws."""
    clean = _plan(strip_result)
    all_bad, all_ties, units = set(), set(), []
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        strip, bad_obs = _corrupt_gcps(strip_quarter, rng)
        bad_ties: set = set()
        monkeypatch.setattr(strip_adjustment, "level1_input", _corrupting_ties(rng, bad_ties))
        res = adjust_strip(strip, _config())
        recall, precision, n = _scores(res, bad_obs, bad_ties)
        print(f"seed {seed}: {len(bad_obs)} GCP measurements + {len(bad_ties)} ties corrupted; "
              f"flagged {n}: recall {recall:.3f} precision {precision:.3f}; check RMS "
              f"{_plan(res):.3f} m vs clean {clean:.3f} m, vendor "
              f"{_plan(res, 'direct'):.2f} m")  # fmt: skip
        assert len(bad_obs) >= 2 and len(bad_ties) >= 20
        assert _plan(res) <= 1.5 * clean + 0.3
        assert res.level1.converged and res.gross_errors.rounds["level1"] >= 1
        flagged = {(f["id"], f["image"]) for f in res.gross_errors.flagged}
        assert bad_obs <= flagged  # named with their sub-scene
        all_bad |= {(seed, *b) for b in bad_obs}
        all_ties |= {(seed, t) for t in bad_ties}
        units.append((recall * (len(bad_obs) + len(bad_ties)), precision * n, n))
    found, right, n = (sum(u[i] for u in units) for i in range(3))
    recall, precision = found / (len(all_bad) + len(all_ties)), right / max(n, 1)
    print(f"all draws: recall {recall:.3f} precision {precision:.3f}")
    assert recall >= 0.95 and precision >= 0.8
    text = res.report.format()
    assert "gross errors:" in text and "removed" in text


@_GROSS
def test_level2_gross_errors_in_the_ties_only_flow(strip_quarter, strip_ties_only):
    """Level 1 on ties only: the GCPs enter at level 2, whose snooping must find their errors."""
    clean = _plan(strip_ties_only)
    found = right = n_flags = n_bad = 0
    for seed in SEEDS:
        strip, bad = _corrupt_gcps(strip_quarter, np.random.default_rng(seed))
        res = adjust_strip(strip, _config(use_gcps=False, bias_prior_sigma=PRIOR))
        recall, precision, n = _scores(res, bad, set())
        print(f"seed {seed}: {len(bad)} GCP measurements corrupted, flagged {n}: recall "
              f"{recall:.3f} precision {precision:.3f}; check RMS {_plan(res):.3f} m vs clean "
              f"{clean:.3f} m")  # fmt: skip
        assert all(f["level"] == 2 for f in res.gross_errors.flagged)
        assert res.gross_errors.rounds["level2"] >= 1
        assert _plan(res) <= 1.5 * clean + 0.3
        w = np.asarray(res.data.gcp_weight)
        o = strip.observations
        rows = res.report.rows["gcp"]
        assert all(w[j] == 0 for j, i in enumerate(rows) if (o.point_ids[i], o.images[i]) in bad)
        found, right = found + recall * len(bad), right + precision * n
        n_flags, n_bad = n_flags + n, n_bad + len(bad)
    assert found / n_bad >= 0.95 and right / max(n_flags, 1) >= 0.8


@_GROSS
def test_wrong_line_offset_is_named(strip_quarter):
    """A sub-scene without GCPs whose line offset is 200 lines too large: its bias absorbs the
    shifted ties (no residual shows it), the seams name it with the offset."""
    scenes = list(strip_quarter.scenes)
    scenes[5] = dataclasses.replace(scenes[5], line_offset=scenes[5].line_offset + 200)
    strip = dataclasses.replace(strip_quarter, scenes=tuple(scenes))
    with pytest.warns(LineOffsetWarning, match=r"scene_005 is probably wrong by \+(19\d|20\d)"):
        res = adjust_strip(strip, _config())
    (a, b) = res.gross_errors.line_offsets
    assert a["scene"] == b["scene"] == "scene_005"
    assert abs(a["row_px"] - 200) < 10 and abs(b["row_px"] + 200) < 10
    assert "scene_005" in res.report.format()
    # why a warning and not a removal: scene_005's check points are off by ~200 px, the others
    # not, and no observation was flagged
    rows = {r["name"]: r["level2"]["plan"] for r in res.report.scenes}
    assert rows["scene_005"] > 50.0 and rows["scene_004"] < 3 * GSD_M


@_GROSS
def test_broken_seams_are_attributed(strip_quarter):
    """A spike (two seams, opposite signs) names its sub-scene, a broken seam at an end the end
    sub-scene, one broken seam inside a step (every sub-scene after it); small seams pass."""
    seams = np.random.default_rng(0).normal(0.0, 2.0, (11, 2))
    assert suspect_offsets(strip_quarter, seams) == []
    seams[4, 1] += 200.0
    seams[5, 1] -= 200.0
    seams[0, 1] -= 150.0
    seams[8, 0] += 60.0
    found = suspect_offsets(strip_quarter, seams)
    assert [(s["a"], s["b"], s["scene"]) for s in found] == [
        ("scene_000", "scene_001", "scene_000"),
        ("scene_004", "scene_005", "scene_005"),
        ("scene_005", "scene_006", "scene_005"),
        ("scene_008", "scene_009", None),
    ]
    assert found[1]["row_px"] == pytest.approx(200.0, abs=10.0)
    text = line_offset_message(found)
    assert re.search(r"scene_005 is probably wrong by \+(19\d|20\d) lines \(too large\)", text)
    assert re.search(r"scene_000 is probably wrong by \+1[45]\d lines", text), text
    assert "scene_008 | scene_009" in text and "from there on" in text


def test_exported_programs_give_the_same_strip(quarter, result, tmp_path, monkeypatch):
    """The CLI's warm path (level 1's solve, level 2 and the evaluation through serialized
    ``jax.export`` programs, ``jaxgeo._runtime.exported``): the same numbers as the suite's
    plain jit."""
    from jaxgeo._runtime import exported as _exported
    from jaxgeo.strip import UniversalCorrectionWarning

    monkeypatch.setenv("JAXGEO_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_exported, "_loaded", {})
    with pytest.warns(UniversalCorrectionWarning):
        again = adjust_strip(quarter, _config())
    assert len(list((tmp_path / "exported").glob("*.jaxexport"))) >= 3
    # the same program, compiled from its serialized form: with XLA's default CPU emitters the
    # numbers are bit-identical; the suite compiles with the legacy ones (tests/conftest.py),
    # which round the two copies differently (3e-8 m on the tie gaps), so equal to rounding
    for a, b in ((again.solution, result.solution), (again.evaluation, result.evaluation)):
        _assert_same_to_rounding(a, b)


def _assert_same_to_rounding(a, b):
    """Equal leaves up to 1e-6 of each array's largest value; geodetic points (``ground``,
    degrees and metres) to 0.1 mm; integers exactly."""
    leaves = jax.tree_util.tree_leaves_with_path(a)
    for (path, x), y in zip(leaves, jax.tree.leaves(b), strict=True):
        x, y, name = np.asarray(x), np.asarray(y), jax.tree_util.keystr(path)
        if not np.issubdtype(y.dtype, np.floating):
            np.testing.assert_array_equal(x, y, err_msg=name)
        elif name.endswith(".ground"):
            metres = np.abs(x - y) * np.array([111e3, 111e3, 1.0])
            assert np.max(metres) < 1e-4, name
        else:
            scale = float(np.max(np.abs(y), initial=0.0, where=np.isfinite(y)))
            np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-6 * scale, err_msg=name)
