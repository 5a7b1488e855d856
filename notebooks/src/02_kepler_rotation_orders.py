# %% [markdown]
# # GCP sweeps: bias-corrected RPCs and the Kepler model's rotation orders
#
# `002_0f5a34c3ba5aae9c.txt` (Cartosat-1 over Warsaw, 36 well-distributed points): the RMSE of
# independent check points (ICPs) as the number and the layout of GCPs change, for the
# vendor RPCs refined with GCPs (table 2) and for the UCL Kepler along-track model with
# constant or first-order rotations (tables 3-7). Here on a **simulated** Warsaw-like pair
# (`jaxgeo.simulate.cartosat1_stereo(site="warsaw")`: flat, 36 points on a jittered grid, 0.3 px
# measurement noise, GCPs surveyed to 0.1 m).
#
# A sweep is many adjustments of one structure: the problem is built once with every point as
# a GCP, and a layout switches the GCP weights of the points it does not use to zero (they
# become check points, adjusted as tie points). All layouts of one model then run in **one**
# jitted, vmapped call of `jaxgeo.lsq.solve`.
#
# *Quick mode* (`QUICK` below: `JAXGEO_NOTEBOOK_QUICK=1`, what the tests set) runs every cell
# on a small sweep: 4 GCP counts with one random layout each, the Kepler model with 5 and 9
# GCPs. Its medians rest on a few layouts: the text, the numbers quoted in it and the paper's
# findings checked below are those of the full sweep (the default), shown here. The last cell
# prints the key numbers, against which `tests/notebooks/test_notebook_02.py` checks the
# statements of the text, on a quick sweep (at its GCP counts) and on this full one.

# %%
import json
import os
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import jaxgeo
from jaxgeo.bundle import direct_georeferencing, prepare, with_bias
from jaxgeo.lsq import RESULTS, SolverConfig, solve
from jaxgeo.models import KeplerSequence, SceneMetadata
from jaxgeo.simulate import Cartosat1Settings, cartosat1_stereo

# quick mode (the tests): fewer GCP counts and layouts in the sweeps, see above
QUICK = os.environ.get("JAXGEO_NOTEBOOK_QUICK") == "1"
QUICK_NOTE = ("(quick mode: a few layouts, not the full sweep)",) if QUICK else ()
T0, C0 = time.perf_counter(), time.process_time()
scene = cartosat1_stereo(1, Cartosat1Settings(site="warsaw"))
obs, ground = scene.observations, scene.ground
all_gcp = ground.with_roles({p: "gcp" for p in ground.ids})
N = len(ground.ids)
print(f"{N} points, heights {ground.lonlath[:, 2].min():.0f}..{ground.lonlath[:, 2].max():.0f} m; "
      f"simulated in {time.perf_counter() - T0:.0f} s")  # fmt: skip
key_numbers = {"quick": QUICK}  # printed as one line at the end (the tests read it)


def num(x):
    """``x`` (a number or an array) rounded to 4 significant digits, for ``key_numbers``."""
    a = np.asarray(x, dtype=float)
    return float(f"{a:.4g}") if a.ndim == 0 else [num(v) for v in a]


# %% [markdown]
# ## Layouts
#
# For every GCP count: a *spread* layout (farthest-point sampling from the scene centre, as a
# surveyor would choose), a *clustered* one (the nearest points to one corner), and random
# draws.

# %%
lonlat = ground.lonlath[:, :2]
xy_m = (lonlat - lonlat.mean(axis=0)) * [np.cos(np.deg2rad(lonlat[:, 1].mean())) * 111e3, 111e3]


def spread(n):
    chosen = [int(np.argmin(np.linalg.norm(xy_m, axis=1)))]
    while len(chosen) < n:
        d = np.min(np.linalg.norm(xy_m[:, None] - xy_m[chosen][None], axis=2), axis=1)
        chosen.append(int(np.argmax(d)))
    return chosen


def clustered(n):
    corner = xy_m.min(axis=0)
    return list(np.argsort(np.linalg.norm(xy_m - corner, axis=1))[:n])


rng = np.random.default_rng(0)
COUNTS = (1, 3, 5, 9) if QUICK else (1, 2, 3, 4, 5, 6, 7, 8, 9, 12, 18)
N_RANDOM = 1 if QUICK else 6
layouts, labels = [], []
for n in COUNTS:
    for kind, idx in [("spread", spread(n)), ("clustered", clustered(n))] + [
        ("random", list(rng.choice(N, n, replace=False))) for _ in range(N_RANDOM)
    ]:
        m = np.zeros(N)
        m[idx] = 1.0
        layouts.append(m)
        labels.append((n, kind))
layouts = np.array(layouts)
print(f"{len(layouts)} layouts")

# %% [markdown]
# ## One vmapped sweep per model
#
# `sweep(models)` builds the problem with all 36 GCPs, then solves every layout at once and
# returns the ICP RMSE east / north / height (m) against the surveyed coordinates, and each
# solve's result (a layout with too few GCPs for the model's parameters comes back
# `undetermined`, from the covariance of that very solve).

# %%
SOLVER = SolverConfig(max_steps=60, loss="l2")  # least squares, as the paper


def sweep(models, counts=COUNTS, prior_sigma=None, prior_weights=None):
    """Solve the layouts with ``counts`` GCPs; returns per layout (all of them) the ICP RMSE
    (NaN where not solved), whether the solve succeeded, and the time of the call.
    ``prior_weights``: several parameter-prior weight vectors, each solved over the layouts in
    the same compiled call (the Kepler rotation orders below)."""
    sel = np.array([n in counts for n, _ in labels])
    setup = prepare(models, obs, all_gcp, prior_sigma=prior_sigma)
    p0 = setup.problem
    if prior_weights is not None:
        out = [sweep_problem(setup, p0, sel, w) for w in prior_weights]
        return [o[:2] for o in out], sum(o[2] for o in out), setup
    return sweep_problem(setup, p0, sel, None)


def sweep_problem(setup, p0, sel, prior_weight):
    if prior_weight is not None:
        p0 = eqx.tree_at(lambda q: q.prior_weight, p0, (jnp.asarray(prior_weight)[None],))
    order = [ground.ids.index(pid) for pid in setup.point_ids]
    surveyed = jnp.asarray(ground.lonlath[order])
    gmask = jnp.asarray(layouts[sel][:, order])  # layout over the problem's points
    t = time.perf_counter()
    rmse, ok = jax.block_until_ready(solve_layouts(p0, surveyed, gmask))
    all_rmse = np.full((len(layouts), 3), np.nan)
    all_ok = np.full(len(layouts), -1)  # -1: not solved (other GCP counts)
    all_rmse[sel], all_ok[sel] = np.asarray(rmse), np.asarray(ok)
    return all_rmse, all_ok, time.perf_counter() - t


def summary(rmse, code, n, kinds=("spread", "clustered", "random"), accept=(0,)):
    """Median RMSE over the layouts of ``n`` GCPs of ``kinds`` whose solve ended with a code in
    ``accept`` (default: solved and determined), and how many there were."""
    sel = [i for i, (k, kind) in enumerate(labels)
           if k == n and kind in kinds and code[i] in accept]  # fmt: skip
    return np.median(rmse[sel], axis=0) if sel else np.full(3, np.nan), len(sel)


STATUS = ("solved", "undetermined", "not converged", "other")


def status(code, n):
    c = code[[i for i, (k, _) in enumerate(labels) if k == n]]
    return ", ".join(f"{(c == j).sum()} {s}" for j, s in enumerate(STATUS) if (c == j).any())


def sweep_results(rmse, code, counts, accept):
    """Per GCP count: the median RMSE east / north / h over the accepted layouts, the spread
    layout's RMSE, the worst layout's 3D RMSE, and how the solves ended (for ``key_numbers``)."""
    out = {}
    for n in counts:
        idx = [i for i, (k, _) in enumerate(labels) if k == n]
        ok = [i for i in idx if code[i] in accept]
        out[str(n)] = {
            "median_m": num(summary(rmse, code, n, accept=accept)[0]),
            "spread_m": num(rmse[labels.index((n, "spread"))]),
            "worst_3d_m": num(np.linalg.norm(rmse[ok], axis=1).max()) if ok else None,
            "status": {s: int((code[idx] == j).sum()) for j, s in enumerate(STATUS)},
        }
    return out


@eqx.filter_jit
def solve_layouts(p0, surveyed, masks):
    """All layouts in one call: ``masks`` (L, points), 1 = GCP, 0 = check point."""

    def one(mask):
        w = p0.ground.weight * mask[p0.ground.point][:, None]
        sol = solve(eqx.tree_at(lambda q: q.ground.weight, p0, w), SOLVER)
        err = (sol.ground - surveyed) * p0.metres_per_unit
        icp = 1.0 - mask
        rmse = jnp.sqrt((icp[:, None] * err**2).sum(0) / icp.sum())
        code = jnp.select(  # 0 solved, 1 undetermined (singular), 2 not converged, 3 other
            [sol.result == RESULTS.successful, sol.result == RESULTS.undetermined,
             sol.result == RESULTS.not_converged], [0, 1, 2], 3)  # fmt: skip
        return rmse, code

    return jax.vmap(one)(masks)


# %% [markdown]
# ## Table 2: vendor RPCs refined with GCPs
#
# Two bias models: a shift (2 parameters per image, from 1 GCP) and an affine bias (6, from
# 3 GCPs); no GCP is direct georeferencing with the vendor RPCs.

# %%
rpc = {}
for bias in ("shift", "affine"):
    rmse, result, dt = sweep(with_bias(scene.vendor, bias))
    rpc[bias] = (rmse, result)
    print(f"RPC + {bias}: {len(layouts)} adjustments in {dt:.1f} s (one call, compilation "
          f"included); determined: {(result == 0).sum()}")  # fmt: skip
direct = direct_georeferencing(scene.vendor, obs, ground.with_roles({p: "check" for p in
                               ground.ids}), roles=("check",)).rms_m  # fmt: skip

PAPER2 = {0: (11.79, 113.81, 760.23), 1: (17.54, 3.38, 5.37), 2: (16.01, 2.33, 5.12),
          3: (2.32, 1.49, 2.29), 4: (1.45, 1.51, 1.93), 5: (1.48, 1.52, 1.96),
          6: (1.48, 1.69, 2.04), 7: (1.50, 1.65, 2.02), 8: (1.43, 1.57, 2.06),
          9: (1.35, 1.54, 2.10)}  # fmt: skip
print(f"\n{'GCPs':>4s} | {'paper x / y / h (m)':>22s} | {'RPC + shift':>22s} | "
      f"{'RPC + affine':>22s}   (median over spread, clustered, {N_RANDOM} random)")  # fmt: skip


def cells(v):
    return " / ".join(f"{x:6.2f}" for x in v)


print(f"{0:4d} | {cells(PAPER2[0])} | {cells(direct)} | {cells(direct)}")
for n in COUNTS:
    paper = cells(PAPER2[n]) if n in PAPER2 else " " * 22
    a = summary(*rpc["shift"], n)[0]
    b = summary(*rpc["affine"], n)[0]
    print(f"{n:4d} | {paper} | {cells(a)} | {cells(b)}")
key_numbers["direct_m"] = num(direct)
key_numbers["rpc"] = {b: sweep_results(*rpc[b], COUNTS, accept=(0,)) for b in rpc}

# %% [markdown]
# The paper's direct georeferencing was far worse in height (760 m): its LPS set-up evaluated
# the RPCs without a proper height; the simulated vendor RPCs are off by tens of metres in
# planimetry and ~5 m in height, as the Hobart ones of the Cartosat-1 paper. With GCPs both
# agree on the shape: the median check-point error is within a pixel (2.5 m, 3D) from 2 GCPs
# on with the shift and from 5 on with the affine bias, with little change beyond. The layout
# matters little for the shift (from 2 GCPs on, the worst of the 8 layouts is at most a third
# above the median), more for the affine bias with few GCPs (the worst layout of 3-7 GCPs
# leaves 5-13 m). Two differences: (1) the paper's 1- and 2-GCP rows
# keep 16-17 m of error in x, where a shift from one GCP here is already at the metre level:
# the simulated vendor error is almost a pure image shift, which one GCP removes, while the
# paper's refinement left a rotation/scale error that needed 3 GCPs; (2) the simulated
# planimetry is 2-3x better than the paper's (0.5-0.9 m against 1.4-1.7 m, from 5 GCPs on):
# the simulated GCPs are surveyed to 0.1 m and measured with 0.3 px noise, real ones are not
# that good. The affine bias is worse than the shift at every count it is determined at (3
# GCPs on), slightly from 5 on (within 20 %): with a pure-shift vendor error, its 4 extra
# parameters per image only fit noise.

# %% [markdown]
# ## Tables 3-7: the Kepler model with rotation orders 0 and 1
#
# `KeplerSequence.from_metadata` places one circular orbit through both images from the scene
# metadata (corners, flying height, view angles, focal length, pixel size, line time, the
# fore/aft interval); the adjustment then estimates the position and velocity of the base
# framelet (6 parameters shared by both images) and per image the attitude angles omega, phi,
# kappa, each constant or with a rate (orders 0 or 1). Metadata from the simulated truth: the
# corners localised at h = 0.

# %%
t_fore = float(scene.truth["fore"].row_time(0.0))


def metadata(name, model, angle_deg):
    n = 12000
    px = np.array([[0.0, 0.0], [n - 1.0, 0.0], [n - 1.0, n - 1.0], [0.0, n - 1.0]])
    return SceneMetadata(name, n, n, np.asarray(model.localize(px, 0.0)), 618e3, angle_deg, 0.0,
                         1945.0, 7.0, 0.336e-3, float(model.row_time(0.0)) - t_fore)  # fmt: skip


start = KeplerSequence.from_metadata(
    [metadata(n, scene.truth[n], a) for n, a in zip(scene.names, (26.0, -5.0), strict=True)],
    orders=(1, 1, 1),
)
ORDERS = {"w0 p0 k0": (0, 0, 0), "w0 p1 k0": (0, 1, 0), "w1 p1 k0": (1, 1, 0),
          "w1 p1 k1": (1, 1, 1)}  # fmt: skip
PAPER_K = {  # tables 3-6: GCPs -> x, y, h (m)
    "w0 p0 k0": {4: (1.41, 1.44, 1.93), 5: (1.43, 1.44, 1.76), 6: (1.43, 1.45, 1.80),
                 9: (1.28, 1.05, 1.77)},
    "w0 p1 k0": {4: (6.07, 1.84, 1.51), 5: (0.98, 1.32, 1.41), 6: (6.36, 1.69, 1.28),
                 9: (0.89, 1.04, 1.11)},
    "w1 p1 k0": {5: (0.88, 1.31, 1.22), 6: (0.87, 1.26, 1.30), 9: (0.85, 1.02, 0.76)},
    "w1 p1 k1": {5: (0.36, 0.93, 0.65), 6: (0.41, 0.91, 0.65), 9: (0.58, 0.79, 0.66)},
}  # fmt: skip
KEPLER_COUNTS = (5, 9) if QUICK else (4, 5, 6, 9, 12)
# One compiled solve for all four orders: the sequence with every rate (orders 1, 1, 1), and
# a rate of order 0 pinned at zero by a prior of 1e-9 rad/s (a few mm over the scan); the
# priors are data, so every order reuses the same compiled call.
full = start.with_orders([(1, 1, 1), (1, 1, 1)])
sigma = eqx.tree_at(lambda q: (q.position_m, q.velocity_m_s, q.attitude), full,
                    (jnp.full(3, jnp.inf), jnp.full(3, jnp.inf),
                     tuple(jnp.ones(6) for _ in full.attitude)))  # fmt: skip
names = prepare({tuple(scene.names): full}, obs, all_gcp, prior_sigma=sigma).param_names


def pinned(o):
    """Prior weights that fix the rates of the angles of order 0."""
    w = np.zeros(len(names))
    for i in range(2):
        for j in range(3):
            if o[j] == 0:
                w[names.index(f"({scene.names[0]}, {scene.names[1]}).attitude[{i}][{3 + j}]")] = 1e9
    return w


outs, dt, _ = sweep({tuple(scene.names): full}, KEPLER_COUNTS, sigma,
                    [pinned(o) for o in ORDERS.values()])  # fmt: skip
kepler = dict(zip(ORDERS, outs, strict=True))
n_kepler = sum(n in KEPLER_COUNTS for n, _ in labels)
print(f"Kepler, 4 rotation orders x {n_kepler} layouts: {4 * n_kepler} adjustments in {dt:.1f} s "
      f"(one compilation)")  # fmt: skip
for name, o in ORDERS.items():
    print(f"  {name}: {6 + 2 * (3 + sum(o))} parameters, determined in "
          f"{(kepler[name][1] == 0).sum()} of {n_kepler} layouts")  # fmt: skip

for name in ORDERS:
    print(f"\nKepler {name}: GCPs | paper x / y / h (m) | jaxgeo, median of all solves | "
          "status of the solves")  # fmt: skip
    for n in KEPLER_COUNTS:
        v, k = summary(*kepler[name], n, accept=(0, 1, 2))
        paper = cells(PAPER_K[name][n]) if n in PAPER_K[name] else " " * 22
        print(f"{n:5d} | {paper} | {cells(v)} | {status(kepler[name][1], n)}")
key_numbers["kepler"] = {
    k: sweep_results(*v, KEPLER_COUNTS, accept=(0, 1, 2)) for k, v in kepler.items()
}

# %% [markdown]
# ## Table 7: all models with 5 GCPs

# %%
print(f"{'method':14s} | {'paper x / y / h (m)':>22s} | {'jaxgeo, spread layout':>22s} | "
      f"{'jaxgeo, median':>22s} | spread layout's solve")  # fmt: skip
PAPER7 = {"RPC": (1.48, 1.52, 1.96), **{k: PAPER_K[k][5] for k in ORDERS}}
rows7 = {"RPC": rpc["affine"], **kepler}
spread5 = labels.index((5, "spread"))
for name, (rmse, result) in rows7.items():
    print(
        f"{name:14s} | {cells(PAPER7[name])} | {cells(rmse[spread5])} | "
        f"{cells(summary(rmse, result, 5, accept=(0, 1, 2))[0])} | {STATUS[result[spread5]]}"
    )
total = {k: float(np.linalg.norm(summary(*v, 5, accept=(0, 1, 2))[0]))
         for k, v in rows7.items()}  # fmt: skip
ratio = total["RPC"] / total["w1 p1 k1"]
print(f"\n3D RMSE with 5 GCPs: RPC {total['RPC']:.2f} m, Kepler w1 p1 k1 "
      f"{total['w1 p1 k1']:.2f} m: ratio {ratio:.2f} (paper: "
      f"{np.linalg.norm(PAPER7['RPC']) / np.linalg.norm(PAPER7['w1 p1 k1']):.2f})")  # fmt: skip
print("paper's finding (first-order rotations 2-3x better than RPCs with 5 GCPs) holds:",
      2.0 <= ratio, *QUICK_NOTE)  # fmt: skip
key_numbers["table7_3d_m"] = {k: num(v) for k, v in total.items()}
key_numbers["table7_ratio"] = num(ratio)

# %% [markdown]
# ## RMSE against the number of GCPs

# %%
fig, axes = plt.subplots(1, 3, figsize=(15, 4.3), sharey=True)
curves = {"RPC + shift": rpc["shift"], "RPC + affine": rpc["affine"],
          **{f"Kepler {k}": v for k, v in kepler.items()}}  # fmt: skip
for i, axis in enumerate(("x / east", "y / north", "h")):
    for j, (name, (rmse, result)) in enumerate(curves.items()):
        ns, med = [], []
        for n in COUNTS:
            v, k = summary(rmse, result, n, accept=(0, 1, 2) if "Kepler" in name else (0,))
            if k:
                ns.append(n)
                med.append(v[i])
        axes[i].semilogy(ns, med, "o-", color=f"C{j}", label=name)
    axes[i].semilogy(list(PAPER2)[1:], [PAPER2[n][i] for n in list(PAPER2)[1:]], "k:",
                     label="paper, RPC (table 2)")  # fmt: skip
    best = PAPER_K["w1 p1 k1"]
    axes[i].semilogy(sorted(best), [best[n][i] for n in sorted(best)], "k--",
                     label="paper, Kepler w1 p1 k1")  # fmt: skip
    axes[i].set(title=f"ICP RMSE {axis}", xlabel="GCPs")
axes[0].set_ylabel("m (median over layouts)")
axes[2].legend(fontsize=7)
fig.tight_layout()
plt.show()

# %% [markdown]
# **Where the simulation and the paper differ, and why.**
#
# - *Status.* jaxgeo flags every Kepler solve as `undetermined` (the singularity test on the
#   covariance of the solve): the orbit position and velocity of the base framelet and the
#   constant attitude angles are almost interchangeable over a 5 s stereo pass (an along-track
#   shift of the orbit and a pitch move the images alike), so some parameter combinations are
#   determined by the GCPs only to within numerical noise. The check points, which depend on
#   the determined combinations, are still accurate; the paper does not discuss the
#   correlation. Fixing the orbit from navigation data (002_'s own recommendation when such
#   data exist) or a prior on it would remove the flag.
# - *Rotation orders.* Constant rotations are worse than the RPCs with 4-6 GCPs (3D RMSE
#   2.8-4.7 m against 2.2-2.6 m, medians). First-order phi alone is the worst order at every
#   GCP count (medians 5-22 m, mostly in height; 4-12 m even with the spread layout; the paper
#   saw 6 m in x with 4 and 6 GCPs and sub-metre with 5 and 9): phi's rate trades against the
#   along-track motion, and nothing in this simulation pins it. First-order omega and phi
#   beat constant rotations at every count. With the spread layout and 5 GCPs they reach the
#   RPC level, with or without kappa (0.57-0.58 / 0.72-0.80 / 1.82-1.85 m against the RPCs'
#   0.56 / 0.71 / 1.83 m); the medians over clustered and random layouts are worse (heights
#   2.05 and 3.72 m with 5 GCPs), and adding kappa's rate (w1 p1 k1, the paper's best) makes
#   them worse with 4-6 GCPs (3D 10.9 / 4.2 / 2.6 m against 2.7 / 2.4 / 2.3 m for w1 p1 k0):
#   of the four orders, w1 p1 k0 has the lowest median at every count here. The 16-18
#   parameter model is more sensitive to the GCP layout than the RPCs, where the paper found
#   the layout unimportant for both.
# - *The 2-3x advantage of first-order rotations over RPCs with 5 GCPs does not appear.* The
#   simulated truth is a smooth rigorous model (polynomial orbit and attitude with a 5 urad
#   wobble) and the vendor RPCs are fitted to a copy of it with constant orbit/attitude
#   offsets: in image space that error is a shift plus a small affine part, which the bias
#   correction removes completely. What remains for every model is the measurement and GCP
#   noise, so the RPCs and the best Kepler model end at the same level at best (0.6 / 0.7 /
#   1.8 m, spread layout), and the Kepler model is worse over random layouts (3D RMSE with 5
#   GCPs: RPC 2.4 m, Kepler first-order 4.2 m, ratio 0.56 where the paper found 2.4).
#   On the real Warsaw data the RPCs (and LPS' refinement of them) evidently left an error that
#   the Kepler model's rates absorbed; a simulation reproduces that only if its vendor RPCs
#   carry such an error (see notebook 1, where a drift and rotation added to the image
#   restore the Cartosat-1 paper's ordering).

# %% [markdown]
# ## The numbers in one line
#
# The key numbers above as one JSON line: `tests/notebooks/test_notebook_02.py` runs this
# notebook (in quick mode) and checks the statements of the text against them.

# %%
print("NOTEBOOK_RESULTS", json.dumps(key_numbers, sort_keys=True))
print(
    f"notebook run time {time.perf_counter() - T0:.0f} s wall, "
    f"{time.process_time() - C0:.0f} s CPU (jaxgeo {jaxgeo.__version__})"
)
