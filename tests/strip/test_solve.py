"""The two-level full-strip adjustment (003_ sections 6-9) on a simulated Carto-2S strip.

One strip with GCPs surveyed in every sub-scene; the two-level adjustment uses only those of a
quarter of the scenes (every fourth and the last, the rule of section 9), the scene-by-scene
adjustment (the practice of the paper's figure 2 and table 1) uses all of them.
"""

import dataclasses
import json

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo.bundle.errors import RESULTS
from jaxgeo.io import read_observations
from jaxgeo.models.rpc_fit import project_points
from jaxgeo.strip import (
    GCPDistributionWarning,
    Level1Config,
    StripConfig,
    StripFormatError,
    adjust_strip,
    read_strip,
)
from jaxgeo.strip.adjustment import adjust_individually, evaluate_models
from jaxgeo.strip.batch import monte_carlo_inputs
from jaxgeo.strip.solve import degree_index, two_level_batch, two_level_jit
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
@pytest.mark.filterwarnings("ignore::jaxgeo.strip.errors.UniversalCorrectionWarning")
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
    """Monte-Carlo runs in one vmapped, jitted call == the same runs one by one.

    Least squares: a vmapped IRLS loop runs every member as long as the slowest one, so a
    robust batch agrees with single runs to the reweighting tolerance only (5e-7 px), and
    compiles twice as long."""
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
