# %% [markdown]
# # Full-strip adjustment of a Carto-2S strip
#
# `003_a7d3ea260371d8c5.txt`: a Carto-2S strip is delivered as tens of overlapping sub-scenes,
# each with its own vendor RPC. Adjusted one by one to their own GCPs, adjacent sub-scenes do
# not meet: the paper's figure 2 shows the steps at the seams. The two-level adjustment forms
# tie points in the overlaps from the known line offsets and bundle-adjusts an affine image
# bias per sub-scene with ties only (level 1: relative), then fits one universal quadratic
# lat/lon correction to the GCPs of the whole strip (level 2: absolute). Section 9 states the
# GCP distribution it needs: a GCP sub-scene among every four, and among the first and the
# last three.
#
# The strip here is simulated by `jaxgeo.simulate.carto2s_strip`: 0.63 m pixels, sub-scenes of
# ~30 km x 15 km overlapping by 1500 lines, vendor RPCs off by ~15 m, GCPs surveyed in every
# sub-scene (so the one-by-one adjustment has its GCPs everywhere; the two-level adjustment
# uses only those of the sub-scenes the rule asks for). `N_SCENES = 44` as the paper's data
# set 1 (C2E, 44 sub-scenes) keeps the notebook within a few minutes on a 2-core machine; set it
# to 80 (or 92, data set 2) for a longer strip: the compiled solve grows linearly, the setup
# in Python too.

# %%
import json
import time
import warnings

import matplotlib.pyplot as plt
import numpy as np

import jaxgeo
from jaxgeo.simulate import Carto2SStripSettings, carto2s_strip
from jaxgeo.strip import (
    GCPDistributionWarning,
    Level1Config,
    Level2Config,
    Strip,
    StripConfig,
    adjust_individually,
    adjust_strip,
    check_gcp_distribution,
    evaluate_models,
)

N_SCENES = 44
T0, C0 = time.perf_counter(), time.process_time()
sim = carto2s_strip(N_SCENES, seed=0, settings=Carto2SStripSettings(gcp_every=1))
full = Strip.from_simulation(sim)
print(f"{N_SCENES} sub-scenes simulated in {time.perf_counter() - T0:.0f} s; GCPs in "
      f"{len(full.gcp_scenes())} of them")  # fmt: skip


def rms(x):
    return float(np.sqrt(np.mean(np.asarray(x) ** 2)))


def num(x):
    """``x`` (a number or an array) rounded to 4 significant digits, for ``key_numbers``."""
    a = np.asarray(x, dtype=float)
    return float(f"{a:.4g}") if a.ndim == 0 else [num(v) for v in a]


key_numbers = {"n_scenes": N_SCENES}  # printed as one line at the end (the tests read it)


# %% [markdown]
# ## Two GCP distributions
#
# *Respecting the rule*: GCPs of every fourth sub-scene and the last. *Violating it*: the same,
# but none in the last third of the strip (the universal correction is then extrapolated
# there). `check_gcp_distribution` runs before any solving and names the runs of sub-scenes
# that break the rule.

# %%
rule = sorted({*range(0, N_SCENES, 4), N_SCENES - 1})
violating = [k for k in rule if k < 2 * N_SCENES // 3]
print("respecting:", rule)
print("violating: ", violating)
for name, keep in (("respecting", rule), ("violating", violating)):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_gcp_distribution(N_SCENES, keep, names=full.names)
    print(f"{name}: {[str(w.message) for w in caught] or 'no warning'}")
    key_numbers[f"warnings_{name}"] = sum(issubclass(w.category, GCPDistributionWarning)
                                      for w in caught)  # fmt: skip

# %% [markdown]
# The paper's flow: level 1 with ties only (relative; an affine bias per sub-scene, with weak
# priors of 50 px and 1e-4 that keep the datum defined), level 2 the quadratic universal
# correction from the GCPs.

# %%
prior = np.array([50.0, 50.0, 1e-4, 1e-4, 1e-4, 1e-4])
config = StripConfig(level1=Level1Config(use_gcps=False, bias_prior_sigma=prior),
                     level2=Level2Config("quadratic"))  # fmt: skip
results = {}
for name, keep in (("respecting", rule), ("violating", violating)):
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GCPDistributionWarning)  # shown above
        results[name] = adjust_strip(full.with_gcp_scenes(keep), config)
    print(f"two-level, GCPs {name} the rule: {time.perf_counter() - t:.0f} s")
t = time.perf_counter()
models, one_by_one = adjust_individually(full)
individual = evaluate_models(results["respecting"], models)
print(f"one by one (every sub-scene with its own GCPs): {time.perf_counter() - t:.0f} s")

# %% [markdown]
# ## Whole-strip figures
#
# Check-point RMS (planimetry, m) and tie gaps at the seams (the distance between a tie point
# localised in one sub-scene and in the next: zero is a seamless mosaic). Paper, table 1:
# direct and "bundle adjusted" ortho RMS of 13-22 m on the real strip (its GCPs and check
# points were themselves at that level: the table shows no accuracy gain, only that the
# universal correction is as good as the individual one); its conclusion: "the same level
# accuracy as individually adjusted", without the discontinuities of figure 2.

# %%
s = results["respecting"].report.strip
v = results["violating"].report.strip
gap_ind = np.hypot(*individual["tie_gap_m"].T)
chk_ind = np.hypot(*individual["check_error_m"].T)
print(f"{'':42s}{'check RMS plan (m)':>20s}{'tie gap RMS / max':>26s}")
for key, label, c, g in (
    ("direct", "vendor RPCs (direct)", s["check_rms_m"]["direct"]["plan"],
     s["tie_gap_m"]["direct"]),
    ("level1", "level 1, ties only", s["check_rms_m"]["level1"]["plan"], s["tie_gap_m"]["level1"]),
    ("respecting", "level 2, GCPs respecting the rule", s["check_rms_m"]["level2"]["plan"],
     s["tie_gap_m"]["level2"]),
    ("violating", "level 2, GCPs violating the rule", v["check_rms_m"]["level2"]["plan"],
     v["tie_gap_m"]["level2"]),
    ("one_by_one", "one by one, GCPs in every sub-scene", rms(chk_ind),
     {"rms": rms(gap_ind), "max": float(gap_ind.max())}),
):  # fmt: skip
    print(f"{label:42s}{c:20.3f}{1e3 * g['rms']:15.1f} / {1e3 * g['max']:.1f} mm")
    key_numbers[key] = {
        "check_plan_m": num(c),
        "gap_rms_m": num(g["rms"]),
        "gap_max_m": num(g["max"]),
    }
print()
print("two-level as accurate as one by one (within 25 %):",
      s["check_rms_m"]["level2"]["plan"] < 1.25 * rms(chk_ind))  # fmt: skip
print(f"seams: one by one {rms(gap_ind):.3f} m RMS vs two-level "
      f"{s['tie_gap_m']['level2']['rms']:.4f} m "
      f"({rms(gap_ind) / s['tie_gap_m']['level2']['rms']:.0f}x smaller)")  # fmt: skip
print("violating the rule costs accuracy (the paper's 'curved effect'):",
      v["check_rms_m"]["level2"]["plan"] > s["check_rms_m"]["level2"]["plan"])  # fmt: skip

# %% [markdown]
# ## The seams along the strip (the paper's figure 2) and the accuracy per sub-scene

# %%
res = results["respecting"]
pair = np.asarray(res.inputs.ties.pair)
assert len(pair) == len(gap_ind)
pairs = np.arange(N_SCENES - 1)
gap_pair_ind = np.array([rms(gap_ind[pair == k]) for k in pairs])
gap_pair_2l = np.array([p["level2"]["rms"] for p in res.report.pairs])
check_scene = np.asarray(res.data.check_scene)
per_scene_ind = np.array([rms(chk_ind[check_scene == k]) for k in range(N_SCENES)])
per_scene = {n: np.array([r["level2"]["plan"] for r in results[n].report.scenes])
             for n in results}  # fmt: skip
direct = np.array([r["direct"]["plan"] for r in res.report.scenes])

fig, axes = plt.subplots(2, 1, figsize=(12, 7), sharex=True)
axes[0].semilogy(pairs + 0.5, gap_pair_ind, "o-", label="one by one")
axes[0].semilogy(pairs + 0.5, gap_pair_2l, "s-", label="two-level")
axes[0].set(ylabel="tie gap RMS at the seam (m)", title="seams between adjacent sub-scenes")
axes[0].legend()
axes[1].semilogy(direct, ".-", color="0.6", label="vendor RPCs")
axes[1].semilogy(per_scene_ind, "o-", label="one by one (own GCPs)")
axes[1].semilogy(per_scene["respecting"], "s-", label="two-level, rule respected")
axes[1].semilogy(per_scene["violating"], "^-", label="two-level, rule violated")
for k in rule:
    axes[1].axvline(k, color="C2", lw=0.5, alpha=0.4)
axes[1].axvspan(max(violating) + 0.5, N_SCENES - 0.5, color="C3", alpha=0.08)
axes[1].set(xlabel="sub-scene (green lines: GCP sub-scenes of the rule; red: no GCP when violated)",
            ylabel="check RMS plan (m)")  # fmt: skip
axes[1].legend(fontsize=8, ncol=2)
fig.tight_layout()
plt.show()
last = slice(max(violating) + 1, N_SCENES)
print(f"check RMS plan over the sub-scenes after the last GCP of the violating layout "
      f"({last.start}..{N_SCENES - 1}): rule respected {rms(per_scene['respecting'][last]):.3f} m, "
      f"violated {rms(per_scene['violating'][last]):.3f} m, one by one "
      f"{rms(per_scene_ind[last]):.3f} m")  # fmt: skip
key_numbers["after_last_gcp"] = {  # check RMS plan over the sub-scenes that violating leaves bare
    "first_scene": last.start,
    "respecting_m": num(rms(per_scene["respecting"][last])),
    "violating_m": num(rms(per_scene["violating"][last])),
    "one_by_one_m": num(rms(per_scene_ind[last])),
    "violating_per_scene_m": num(per_scene["violating"][last]),
}

# %% [markdown]
# What the simulation shows, against the paper: scenes adjusted one by one leave gaps of
# metres at the seams (1.5 m RMS, 7.6 m at worst on the 44-scene run: several pixels) and the
# two-level adjustment closes them to a fraction of a millimetre, at the same or better
# check-point accuracy (the paper's conclusion and figure 2; better here because an affine
# bias fitted to the 4 GCPs of one sub-scene partly fits their noise, while the universal
# correction pools the GCPs of the whole strip). With no GCP in the last third, the quadratic
# correction is extrapolated there and the error grows towards the end of the strip (the
# "curved effect" of section 9); the rule's check before solving names the gap. The paper's
# absolute numbers (13-22 m in table 1) are not comparable: its reference data were at that
# level; the simulation's GCPs are surveyed to 0.1 m.

# %% [markdown]
# ## The numbers in one line
#
# The key numbers above as one JSON line: `tests/notebooks/test_notebook_03.py` runs this
# notebook and checks the statements of the text against them.

# %%
print("NOTEBOOK_RESULTS", json.dumps(key_numbers, sort_keys=True))
print(
    f"notebook run time {time.perf_counter() - T0:.0f} s wall, "
    f"{time.process_time() - C0:.0f} s CPU (jaxgeo {jaxgeo.__version__})"
)
