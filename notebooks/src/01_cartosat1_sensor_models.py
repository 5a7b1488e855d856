# %% [markdown]
# # Cartosat-1 sensor models: 3D affine, bias-corrected RPCs, generic pushbroom
#
# The comparison of `000_5aba1cb50921f3c6.txt` (Cartosat-1 over Hobart) on a **simulated**
# pair: the embedded demo scene of `jaxgeo.simulate` (fore +26 deg / aft -5 deg, 2.5 m pixels,
# 69 GPS points in the top-left quarter of the scene, 9 GCPs and 60 check points, 0.3 px
# measurement noise, vendor RPCs biased by tens of pixels). Stochastic model as in the paper:
# a priori 0.5 px for image coordinates and 0.3 m for GCP coordinates, least squares (not
# jaxgeo's default robust loss and data snooping: the simulated measurements carry no gross
# error); check points are adjusted as tie points and compared with their surveyed
# coordinates.
#
# Every table prints the paper's value beside jaxgeo's. The simulation is not Hobart: its
# vendor errors, terrain and point field are synthetic, so the numbers are compared for their
# size and their ordering, not digit by digit.
#
# *Quick mode* (`QUICK` below: `JAXGEO_NOTEBOOK_QUICK=1`, what the tests set) runs every cell
# with fewer variants, each of which is one more compiled adjustment: table 4 without the
# shift+drift bias, table 5 with 1 GCP only, table 2 in geocentric space only, table 6 with 9
# GCPs only. The comparisons that need a missing variant are printed in the full run only,
# and the text discusses the full run (the default), shown here; the last cell prints the key
# numbers, against which `tests/notebooks/test_notebook_01.py` checks the statements of the
# text, on a quick run as far as its variants go and on this full run.

# %%
import json
import os
import time
from types import SimpleNamespace

import equinox as eqx
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import jaxgeo
from jaxgeo.bundle import adjust, direct_georeferencing
from jaxgeo.io import Observations, read_ground, read_observations, read_rpc
from jaxgeo.lsq import SolverConfig
from jaxgeo.models import Affine3D, EphemerisModel, GenericPushbroom, SceneMetadata
from jaxgeo.simulate import demo_dir

# quick mode (the tests): fewer variants in tables 4, 5, 2 and 6, see above
QUICK = os.environ.get("JAXGEO_NOTEBOOK_QUICK") == "1"
SOLVER = SolverConfig(loss="l2", remove_blunders=False)  # least squares, as the paper
T0, C0 = time.perf_counter(), time.process_time()
d = demo_dir()  # written by jaxgeo.simulate.write_demo; the tests regenerate it byte for byte
truth_json = json.loads((d / "truth.json").read_text())
scene = SimpleNamespace(
    names=("fore", "aft"),
    vendor={n: read_rpc(d / f"{n}.txt") for n in ("fore", "aft")},
    truth={
        n: EphemerisModel.from_dict(truth_json["images"][n]["truth_model"]) for n in ("fore", "aft")
    },  # fmt: skip
)
obs, ground = read_observations(d / "observations.csv"), read_ground(d / "ground.csv")
gcp_ids = [p for p, r in zip(ground.ids, ground.role, strict=True) if r == "gcp"]
print(f"{len(ground.ids)} points ({len(gcp_ids)} GCPs), {len(obs.point_ids)} image measurements")
key_numbers = {"quick": QUICK}  # printed as one line at the end (the tests read it)


# %%
def table(title, columns, rows):
    """Print rows of (label, paper values..., jaxgeo values...) under ``columns``."""
    w = max(14, *(len(c) + 2 for c in columns))
    print(title)
    print(f"{'':24s}" + "".join(f"{c:>{w}s}" for c in columns))
    for label, *values in rows:
        cells = "".join(f"{v:>{w}s}" if isinstance(v, str) else f"{v:{w}.2f}" for v in values)
        print(f"{label:24s}{cells}")
    print()


def report_rows(paper, results, names=("fore", "aft")):
    """Rows of the paper's tables 2-6: image RMS x/y per image, object RMS, min/max, s0.

    ``paper``: per column, (rms_x fore, rms_x aft, rms_y fore, rms_y aft, X, Y, Z, s0);
    ``results``: per column, an AdjustResult (or an AccuracyReport)."""
    reps = [getattr(r, "report", r) for r in results]
    rows = []
    for i, key in enumerate(("RMS x", "RMS y")):
        for j, name in enumerate(names):
            rows.append((f"{key} {name} [px]", *[p[2 * i + j] for p in paper],
                         *[rep.images[name][i] for rep in reps]))  # fmt: skip
    for k, axis in enumerate("XYZ"):
        rows.append((f"RMS {axis} [m]", *[p[4 + k] for p in paper],
                     *[rep.rms_m[k] for rep in reps]))  # fmt: skip
        rows.append((f"  min/max {axis} [m]", *["" for _ in paper],
                     *[f"{rep.min_m[k]:.1f}/{rep.max_m[k]:.1f}" for rep in reps]))  # fmt: skip
    rows.append(("s0", *[p[7] for p in paper], *[rep.s0 for rep in reps]))
    return rows


def num(x):
    """``x`` (a number or an array) rounded to 4 significant digits, for ``key_numbers``."""
    a = np.asarray(x, dtype=float)
    return float(f"{a:.4g}") if a.ndim == 0 else [num(v) for v in a]


def column(r):
    """The key numbers of one table column (an AdjustResult or an AccuracyReport): check-point
    RMS east / north / up (m), the largest image RMS over images and x / y (px), s0."""
    rep = getattr(r, "report", r)
    return {"rms_m": num(rep.rms_m), "s0": num(rep.s0),
            "image_rms_px": num(max(max(v[:2]) for v in rep.images.values()))}  # fmt: skip


# %% [markdown]
# ## Table 3: direct georeferencing with the vendor RPCs
#
# Forward intersection of the check points with the RPCs as delivered (no GCP). Object
# errors are east / north / up in metres.

# %%
direct = direct_georeferencing(scene.vendor, obs, ground, roles=("check",))
table(
    "Table 3 (paper: Hobart) vs jaxgeo (simulated)",
    ["paper", "jaxgeo"],
    report_rows([(0.91, 15.92, 33.27, 26.80, 2.7, 72.6, 25.9, 22.46)], [direct]),
)
key_numbers["direct"] = column(direct)

# %% [markdown]
# ## Table 4: RPC + image-space bias, 9 GCPs
#
# `jaxgeo.adjust(models, observations, ground, bias=...)` wraps each RPC in
# `Biased(rpc, ShiftBias() | ShiftDriftBias() | AffineBias())` (eq. 2 of the paper) and adjusts
# the bias parameters together with the points.

# %%
BIASES = ("shift", "affine") if QUICK else ("shift", "shift-drift", "affine")
PAPER4 = {
    "shift": (0.25, 0.26, 0.78, 0.44, 0.66, 1.12, 2.23, 0.59),
    "shift-drift": (0.25, 0.26, 0.74, 0.46, 0.66, 1.16, 1.99, 0.47),
    "affine": (0.25, 0.26, 0.52, 0.40, 0.65, 0.95, 1.67, 0.38),
}
t = time.perf_counter()
biased = {b: adjust(scene.vendor, obs, ground, bias=b, solver=SOLVER) for b in BIASES}
print(f"{len(BIASES)} adjustments in {time.perf_counter() - t:.1f} s (compilation included)\n")
table(
    "Table 4: paper (shift, shift+drift, affine) | jaxgeo (same)",
    [f"paper {b}" for b in BIASES] + [f"jaxgeo {b}" for b in BIASES],
    report_rows([PAPER4[b] for b in BIASES], [biased[b] for b in BIASES]),
)
h4 = {b: biased[b].report.rms_m[2] for b in BIASES}
key_numbers["table4"] = {b: column(biased[b]) for b in BIASES}
print("height RMS (m):", {b: round(v, 2) for b, v in h4.items()})
if not QUICK:  # needs the three biases
    print("paper's ordering affine < shift+drift < shift in height holds:",
          h4["affine"] < h4["shift-drift"] < h4["shift"])  # fmt: skip

# %% [markdown]
# **Does the paper's ordering hold?** On this simulation, *no*: all three bias models reach the same
# sub-pixel accuracy, and the extra drift / affine parameters mostly fit noise (heights within a few
# centimetres of each other, the shift's the best). The reason is the simulated vendor error:
# `jaxgeo.simulate` perturbs the orbit and attitude by constant offsets over a 5 s scan, which in
# image space is almost a pure shift. The real Cartosat-1 RPCs of the paper also had a drift and a
# rotation (s0 falls from 0.59 to 0.38 in table 4: the shift model left a systematic error). Adding
# such an error to the fore image (1.5 px of along-track drift over the scene, ~1 px of rotation at
# the edges) restores the paper's ordering, and the shift model's s0 rises above the others' (0.70
# against 0.59). The added error is affine in the image, so the affine bias absorbs it completely:
# its column does not change.

# %%
x, y = obs.xy[:, 0], obs.xy[:, 1]
fore = np.array([img == "fore" for img in obs.images])[:, None]
drift_rot = np.stack([1.5e-4 * (y - 6000.0), 1.25e-4 * y + 1.5e-4 * (x - 6000.0)], axis=1)
distorted = Observations(obs.point_ids, obs.images, obs.xy + fore * drift_rot, obs.sigma_px)
biased_d = {b: adjust(scene.vendor, distorted, ground, bias=b, solver=SOLVER) for b in BIASES}
table(
    "Table 4 with a drift + rotation added to the fore image",
    [f"paper {b}" for b in BIASES] + [f"jaxgeo {b}" for b in BIASES],
    report_rows([PAPER4[b] for b in BIASES], [biased_d[b] for b in BIASES]),
)
h4d = {b: biased_d[b].report.rms_m[2] for b in BIASES}
key_numbers["table4_distorted"] = {b: column(biased_d[b]) for b in BIASES}
if not QUICK:  # needs the three biases
    print("ordering affine < shift+drift < shift in height holds:",
          h4d["affine"] < h4d["shift-drift"] < h4d["shift"])  # fmt: skip
print("s0:", {b: round(biased_d[b].s0, 2) for b in BIASES})

# %% [markdown]
# ## Table 5: minimal control (shift with 1 GCP, shift+drift with 3 GCPs)

# %%
MINIMAL = {1: "shift"} if QUICK else {1: "shift", 3: "shift-drift"}  # GCPs: bias
PAPER5 = {1: (0.46, 0.47, 0.79, 0.46, 1.17, 1.11, 2.44, 0.38),
          3: (0.27, 0.28, 1.03, 0.62, 0.77, 1.61, 2.24, 0.35)}  # fmt: skip
minimal = {k: adjust(scene.vendor, obs, ground.with_roles({p: "check" for p in gcp_ids[k:]}),
                     bias=b, solver=SOLVER) for k, b in MINIMAL.items()}  # fmt: skip
table(
    "Table 5: paper (shift/1 GCP, shift+drift/3 GCPs) | jaxgeo",
    [f"paper {k}" for k in MINIMAL] + [f"jaxgeo {k}" for k in MINIMAL],
    report_rows([PAPER5[k] for k in MINIMAL], [minimal[k] for k in MINIMAL]),
)
key_numbers["table5"] = {str(k): column(minimal[k]) for k in MINIMAL}
print("one GCP worse in height than nine (as in the paper):",
      minimal[1].report.rms_m[2] > biased["shift"].report.rms_m[2])  # fmt: skip

# %% [markdown]
# ## Table 2: the 3D affine model in geocentric, geographic and UTM object space
#
# `Affine3D.fit` gives the initial 8 parameters per image from the 9 GCPs (linear least
# squares); `adjust` then refines them with the points, as a bundle adjustment.

# %%
SPACES = ("geocentric",) if QUICK else ("geocentric", "geographic", "utm")
PAPER2 = {
    "geocentric": (0.32, 0.32, 0.55, 0.41, 1.20, 0.96, 1.33, 0.42),
    "geographic": (0.54, 0.55, 0.56, 0.54, 1.43, 1.17, 1.81, 0.53),
    "utm": (0.33, 0.33, 0.53, 0.42, 0.80, 1.00, 1.81, 0.41),
}
rows_of = {n: {p: i for i, (p, m) in enumerate(zip(obs.point_ids, obs.images, strict=True))
               if m == n} for n in scene.names}  # fmt: skip
gi = [ground.ids.index(p) for p in gcp_ids]
affine3d = {}
for space in SPACES:
    models = {n: Affine3D.fit(ground.lonlath[gi], obs.xy[[rows_of[n][p] for p in gcp_ids]],
                              space=space, zone=55, north=False) for n in scene.names}  # fmt: skip
    affine3d[space] = adjust(models, obs, ground, solver=SOLVER)
table(
    "Table 2: paper (geocentric, geographic, UTM) | jaxgeo (same)",
    [f"paper {s[:5]}" for s in SPACES] + [f"jaxgeo {s[:5]}" for s in SPACES],
    report_rows([PAPER2[s] for s in SPACES], [affine3d[s] for s in SPACES]),
)

# %% [markdown]
# The paper found the 3D affine model slightly worse than affine-biased RPCs, and the
# geographic space worst (object RMS up to 1.8 m). The 3D affine model is a parallel
# projection: it ignores the perspective across the 30 km swath, which over 1260 m of
# relief is several pixels; the simulation only has the 9 GCPs of one quarter to fit it.
# jaxgeo finds both orderings of the paper: planimetric RMS 1.5 m (geocentric), 2.7 m
# (geographic) and 1.5 m (UTM), against 0.9 m for the RPCs with an affine bias.

# %%
plan = {s: float(np.hypot(*affine3d[s].report.rms_m[:2])) for s in SPACES}
key_numbers["table2"] = {s: {**column(affine3d[s]), "plan_m": num(plan[s])} for s in SPACES}
key_numbers["rpc_affine_plan_m"] = num(np.hypot(*biased["affine"].report.rms_m[:2]))
print(
    "planimetric RMS (m):",
    {s: round(v, 2) for s, v in plan.items()},
    "| affine-biased RPC:",
    round(float(np.hypot(*biased["affine"].report.rms_m[:2])), 2),
)
if not QUICK:  # needs the three spaces
    print("geographic worst (as in the paper):", plan["geographic"] == max(plan.values()))
print("3D affine worse than RPC + affine bias (as in the paper):",
      min(plan.values()) > float(np.hypot(*biased["affine"].report.rms_m[:2])))  # fmt: skip


# %% [markdown]
# ## Table 6: generic pushbroom model with 9 and 15 GCPs
#
# `GenericPushbroom.from_metadata` initialises the orbit and attitude splines (degree 2) from
# the scene corners, the flying height, the focal length, the pixel size and the view angles
# (section 3.3.1); the soft orbit constraints of 3.3.2 (orbit in a plane through the Earth
# centre, almost circular) are part of the model. The metadata here comes from the simulated
# truth (corners localised at h = 0), as a vendor's metadata file would give it.
#
# With those constraints alone (`adjust(start, obs, ground)`), jaxgeo's adjustment refuses
# this block: it raises
# `SingularNormalEquations` naming the orbit and attitude control points. With all points in
# one quarter of the scene, a shift of the orbit and a rotation of the attitude move the
# image alike, and the normal equations cannot separate them. The paper's Barista solution
# did not report this; jaxgeo says so rather than return an arbitrary split. Below, a loose
# prior (1 km on the orbit control points, 0.01 rad on the attitude ones: what any
# navigation data or the metadata itself supports) makes the split determined.


# %%
def metadata(name, model, angle_deg):
    n = 12000
    px = np.array([[0.0, 0.0], [n - 1.0, 0.0], [n - 1.0, n - 1.0], [0.0, n - 1.0]])
    corners = np.asarray(model.localize(px, 0.0))
    return SceneMetadata(name, n, n, corners, 618e3, angle_deg, 0.0, 1945.0, 7.0, 0.336e-3)


start = {n: GenericPushbroom.from_metadata(metadata(n, scene.truth[n], a))
         for n, a in zip(scene.names, (26.0, -5.0), strict=True)}  # fmt: skip
non_gcp = [p for p in ground.ids if p not in gcp_ids]
g15 = ground.with_roles({p: "gcp" for p in non_gcp[:6]})  # 6 more, spread by the simulation
prior = {
    n: eqx.tree_at(
        lambda q: (q.orbit.coeffs, q.attitude.coeffs),
        m,
        (jnp.full_like(m.orbit.coeffs, 1000.0), jnp.full_like(m.attitude.coeffs, 0.01)),
    )
    for n, m in start.items()
}
GCPS6 = {9: ground} if QUICK else {9: ground, 15: g15}
PAPER6 = {9: (0.27, 0.30, 0.54, 0.41, 1.29, 0.81, 1.35, 0.38),
          15: (0.27, 0.27, 0.59, 0.42, 1.29, 0.91, 1.45, 0.44)}  # fmt: skip
pushbroom = {k: adjust(start, obs, g, prior_sigma=prior, solver=SOLVER) for k, g in GCPS6.items()}
table(
    "Table 6: paper (9, 15 GCPs) | jaxgeo (same)",
    [f"paper {k}" for k in GCPS6] + [f"jaxgeo {k}" for k in GCPS6],
    report_rows([PAPER6[k] for k in GCPS6], [pushbroom[k] for k in GCPS6]),
)
key_numbers["table6"] = {
    str(k): {
        **column(r),
        "plan_m": num(np.hypot(*r.report.rms_m[:2])),
        "converged": bool(r.converged),
    }
    for k, r in pushbroom.items()
}
print("converged:", {k: r.converged for k, r in pushbroom.items()},
      "steps:", {k: r.num_steps for k, r in pushbroom.items()})  # fmt: skip

# %% [markdown]
# The pushbroom model reaches the paper's object-space level in planimetry (0.8-1.4 m
# against 0.8-1.3 m), but not in height (2.1-2.6 m against 1.4 m), and its s0 (2.3-2.4 here
# against 0.38-0.44 in the paper) and image RMS (0.4-0.6 px) show that it does not fit the
# simulated images to their noise (0.3 px). Unlike the paper (9 GCPs slightly better than
# 15), the 6 extra GCPs help here, as they should for a model that is short of freedom. The
# likely reason: the simulated truth's attitude carries a smooth 5 urad wobble (a degree-5
# polynomial over the 4 s scan), about a pixel on the ground, which one degree-2 spline
# segment cannot follow; the vendor RPCs were fitted to the full truth and keep it, so the
# bias-corrected RPCs do not see it.
# (`GenericPushbroom.from_metadata(..., n_segments=2)` gives the splines more freedom.)

# %% [markdown]
# ## Residual vectors over the image and on the ground
#
# Check-point image residuals (back-projected - measured, px, exaggerated) for the shift and
# affine biases on the distorted fore image, and the check-point errors on the ground
# (adjusted - surveyed, east / north arrows, height as colour).

# %%
fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
for ax, b in zip(axes[:2], ("shift", "affine"), strict=True):
    r = biased_d[b]
    sel = np.array(
        [
            img == "fore" and p not in gcp_ids
            for p, img in zip(r.observation_ids, r.observation_images, strict=True)
        ]
    )
    xy = distorted.xy[sel]
    res = r.residuals_px[sel]
    ax.quiver(xy[:, 0], xy[:, 1], res[:, 0], -res[:, 1], angles="xy", scale_units="xy",
              scale=1 / 1000, color="C0")  # fmt: skip
    ax.set(title=f"fore, {b} bias: residuals x1000", xlabel="x (col) px", ylabel="y (row) px",
           xlim=(0, 12000), ylim=(12000, 0))  # fmt: skip
rep = biased["affine"].report
enu = rep.errors_m
where = np.array([ground.lonlath[ground.ids.index(p)] for p in rep.ids])
q = axes[2].quiver(where[:, 0], where[:, 1], enu[:, 0], enu[:, 1], enu[:, 2], cmap="coolwarm")
axes[2].set(title="ground errors, RPC + affine bias (arrows E/N, colour h)", xlabel="lon (deg)",
            ylabel="lat (deg)")  # fmt: skip
axes[2].tick_params(axis="x", rotation=30)
fig.colorbar(q, ax=axes[2], label="height error (m)")
gcp_ll = ground.lonlath[gi]
axes[2].plot(gcp_ll[:, 0], gcp_ll[:, 1], "k^", label="GCP")
axes[2].legend()
fig.tight_layout()
plt.show()

# %% [markdown]
# ## The numbers in one line
#
# The key numbers above as one JSON line: `tests/notebooks/test_notebook_01.py` runs this
# notebook (in quick mode) and checks the statements of the text against them.

# %%
print("NOTEBOOK_RESULTS", json.dumps(key_numbers, sort_keys=True))
print(
    f"notebook run time {time.perf_counter() - T0:.0f} s wall, "
    f"{time.process_time() - C0:.0f} s CPU (jaxgeo {jaxgeo.__version__})"
)
