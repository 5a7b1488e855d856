"""Gross errors in a strip: data snooping at both levels, and the seams of the line offsets.

Level 1 is a bundle adjustment and is snooped as one (:func:`jaxgeo.bundle.snoop`:
robust loss solved by IRLS, Baarda's w-test with redundancy numbers, the worst flagged
observations removed and the block re-solved). Level 2 is a small weighted linear fit (the
universal correction) and gets the same treatment here with the same settings
(``SolverConfig.loss``, ``loss_scale``, ``irls_*``, ``blunder_k``, ``remove_blunders``,
``snooping_rounds``): GCP measurements removed at level 1 (image observation or coordinates) are
left out; the others are fitted with the robust loss' IRLS weights
(:func:`jaxgeo.lsq.irls_weights`), tested with ``w = e / (sigma sqrt(r))`` (``r`` the
redundancy number of the weighted fit) and the worst removed, refitted, until none is flagged.

A wrong line offset shifts every formed tie of a sub-scene by the same amount: the sub-scene's
bias absorbs it (no residual, nothing to snoop) unless the sub-scene has GCPs. It shows, before
any adjustment, at the seams: the vendor RPCs of two adjacent sub-scenes agree at their ties to a
few pixels, and a sub-scene whose offset is wrong by ``D`` lines disagrees with both neighbours
by ``D`` (opposite signs). :func:`seam_offsets` measures it, :func:`suspect_offsets` names them.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ..bundle.internal import MAX_REMOVED_FRACTION, ROBUST_FRACTION
from ..lsq import Problem, Solution, SolverConfig
from ..lsq.internal import irls_weights
from ..models import project_points
from ._delivery import Strip
from ._level1 import Level1Input
from ._level2 import Level2Data
from ._solve import TwoLevelSolution, degree_index, level_two_jit
from ._universal import N_TERMS, _terms

SEAM_LIMIT_PX = 20.0
"""A seam whose formed ties the two vendor RPCs put further apart than this (px, beyond the
strip's median seam) is broken: a line offset is wrong (vendor RPCs of one pass agree at the
seams to a few pixels; the simulated Carto-2S strips to < 5 px)."""


def level2_standardized(
    sol: TwoLevelSolution, weight: np.ndarray, sigma_m: np.ndarray
) -> np.ndarray:
    """Standardised residuals ``(g, 2)`` (east, north) of the level-2 GCP measurements in the
    fit weighted by ``weight / sigma_m**2`` (NaN where the redundancy number is ~0)."""
    k = list(N_TERMS.values())[int(sol.degree_index)]
    e = np.asarray(sol.gcp_error_level2_m)
    c = sol.correction
    g1 = np.asarray(sol.gcp_level1)
    lat_n = (g1[:, 1] - float(c.offset[0])) / float(c.scale[0])
    lon_n = (g1[:, 0] - float(c.offset[1])) / float(c.scale[1])
    t = np.asarray(_terms(jnp.asarray(lat_n), jnp.asarray(lon_n)))[:, :k]
    p = weight / sigma_m**2
    if k:
        n = t.T @ (p[:, None] * t)
        h = p * np.einsum("ik,ik->i", t @ np.linalg.pinv(n), t)
    else:
        h = np.zeros(len(p))
    red = 1.0 - h
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(
            (red > 1e-10)[:, None],
            e / (sigma_m * np.sqrt(np.maximum(red, 1e-300)))[:, None],
            np.nan,
        )


@dataclasses.dataclass(frozen=True)
class Level2Snooping:
    """What level 2's snooping found: ``solution`` (the last fit), ``weight`` (g,) its weights,
    ``removed`` (g,) the GCP measurements left out (``removed_level1``: already at level 1),
    ``w`` (g,) the largest ``|standardised residual|`` of each, ``rounds`` refits after
    removals, ``converged`` whether the reweighting settled."""

    solution: TwoLevelSolution
    weight: np.ndarray
    removed: np.ndarray
    removed_level1: np.ndarray
    w: np.ndarray
    rounds: int
    converged: bool


LEVEL2_IRLS_TOL = 1e-3
"""Weight change below which level 2's reweighting stops (or ``SolverConfig.irls_tol``, if
tighter): level 2 has no final robust solve, its last reweighted fit is the answer."""


def _irls(problem, data, level1, degree, solver, keep):
    """Robust level-2 fit: least squares, then reweighted fits until the weights settle."""
    tol = min(float(solver.irls_tol), LEVEL2_IRLS_TOL)
    sigma = np.asarray(data.gcp_sigma_m)
    w = keep.astype(float)
    for _ in range(solver.irls_iterations + 1):
        d = _with_weight(data, w)
        sol = level_two_jit(problem, d, level1, degree)
        if solver.loss == "l2":
            return sol, w, True
        e = np.asarray(sol.gcp_error_level2_m) / sigma[:, None]
        new = keep * np.asarray(irls_weights(jnp.asarray(np.sum(e**2, axis=1)), solver.loss,
                                             float(solver.loss_scale)))  # fmt: skip
        if np.max(np.abs(new - w), initial=0.0) <= tol:
            return sol, w, True
        w = new
    return sol, w, False


def _with_weight(data: Level2Data, w: np.ndarray) -> Level2Data:
    import equinox as eqx

    return eqx.tree_at(lambda t: t.gcp_weight, data, jnp.asarray(w, dtype=float))


def snoop_level2(
    problem: Problem,
    data: Level2Data,
    level1: Solution,
    degree,
    solver: SolverConfig,
    removed_level1: np.ndarray,
) -> Level2Snooping:
    """Level 2 robust, then its data snooping (see the module docstring); ``removed_level1``
    (g,) the GCP measurements removed at level 1."""
    degree = degree_index(degree)
    sigma = np.asarray(data.gcp_sigma_m)
    removed = np.asarray(removed_level1, dtype=bool).copy()
    g = removed.size
    limit = solver.snooping_rounds if solver.remove_blunders else 0
    rounds = 0
    while True:
        sol, weight, converged = _irls(problem, data, level1, degree, solver, ~removed)
        std = level2_standardized(sol, weight, sigma)
        w = np.max(np.abs(np.nan_to_num(std)), axis=1) if g else np.zeros(0)
        test = np.where(removed, 0.0, w)
        worst = test.max(initial=0.0)
        if rounds >= limit or not worst > solver.blunder_k:
            break
        cut = worst if solver.loss == "l2" else max(solver.blunder_k, ROBUST_FRACTION * worst)
        pick = test >= cut
        if np.sum(removed | pick) > MAX_REMOVED_FRACTION * g:
            break
        removed |= pick
        rounds += 1
    return Level2Snooping(sol, weight, removed, np.asarray(removed_level1, bool), w, rounds,
                          converged)  # fmt: skip


def seam_offsets(strip: Strip, inp: Level1Input) -> np.ndarray:
    """Per adjacent pair ``(S - 1, 2)``: the median ``(col, row)`` px by which the second
    sub-scene's vendor RPC projects the formed ties (localised in the first at their height)
    away from where the line offsets put them (NaN for a pair without ties)."""
    t = inp.ties
    pair = np.argsort(t.point, kind="stable").reshape(-1, 2)  # (t, 2) rows: scene k, k + 1
    second = t.scene[pair[:, 1]]
    out = np.full((len(strip.names) - 1, 2), np.nan)
    for k in range(len(strip.names) - 1):
        sel = np.flatnonzero(t.pair == k)
        if not sel.size:
            continue
        ground = inp.tie_lonlath[sel]
        name = strip.names[int(second[sel[0]])]
        xy = np.asarray(project_points(strip.rpcs[name], ground))
        out[k] = np.median(xy - t.xy[pair[sel, 1]], axis=0)
    return out


def suspect_offsets(strip: Strip, seams: np.ndarray, limit_px: float = SEAM_LIMIT_PX) -> list[dict]:
    """The broken seams (beyond ``limit_px`` from the strip's median seam, or from 0 with fewer
    than 3 seams), each
    ``{a, b, col_px, row_px, scene}``: ``scene`` the sub-scene whose line offset is likely wrong
    (both its seams broken with opposite row signs, or a broken seam at an end of the strip
    whose neighbour is fine), else ``None`` (a step: every sub-scene after the seam shifted).
    ``row_px``: lines by which the second sub-scene's ``first_line`` is too large (or, with
    ``scene`` the first, too small)."""
    names = strip.names
    if not len(seams):
        return []
    # beyond the strip's median seam (a convention shared by every offset is no error); with
    # fewer than 3 seams the median is no reference: the seams themselves
    dev = seams - np.nanmedian(seams, axis=0) if len(seams) >= 3 else seams
    broken = np.nan_to_num(np.hypot(*dev.T)) > limit_px
    out = []
    for k in np.flatnonzero(broken):
        scene = None
        prev_ok = k == 0 or not broken[k - 1]
        next_ok = k == len(broken) - 1 or not broken[k + 1]
        if k + 1 < len(broken) and broken[k + 1] and dev[k, 1] * dev[k + 1, 1] < 0:
            scene = names[k + 1]
        elif k > 0 and broken[k - 1] and dev[k, 1] * dev[k - 1, 1] < 0:
            scene = names[k]
        elif k == 0 and next_ok:
            scene = names[0]
        elif k == len(broken) - 1 and prev_ok:
            scene = names[-1]
        out.append({"a": names[k], "b": names[k + 1], "col_px": float(dev[k, 0]),
                    "row_px": float(dev[k, 1]), "scene": scene})  # fmt: skip
    return out


CHECK_K = 5.0
"""A check measurement whose level-2 error departs from the other checks of its sub-scene by
more than this many robust sigmas is a gross error of the check itself (:func:`gross_checks`)."""
CHECK_FLOOR_M = 0.05
"""The robust sigma of :func:`gross_checks` is at least this (m): exact simulated checks must
not make centimetre departures gross."""
CHECK_MIN_PER_SCENE = 3
"""Checks a sub-scene needs before one of them can be told apart from the others."""
CHECK_MIN_JUDGED = 5
"""Checks (in sub-scenes that have enough) the robust sigma of :func:`gross_checks` needs."""


def gross_checks(
    scene: np.ndarray, error_m: np.ndarray, k: float = CHECK_K, floor_m: float = CHECK_FLOOR_M
) -> np.ndarray:
    """The check measurements (c,) bool whose final error is a gross error of their own.

    Check points never enter the adjustment (mono-plotted afterwards), so no w-test sees them;
    a wrong check measurement or surveyed position would otherwise inflate the statistics that
    judge the adjustment. ``error_m`` (c, 2) east/north error after level 2 (m), ``scene`` (c,)
    their sub-scene. A check is compared with the median error of its own sub-scene's checks
    (the correction's error varies along the strip, and a sub-scene whose model is wrong, e.g.
    its line offset, moves all its checks alike: that is the model's error, never hidden), and
    flagged when the departure exceeds ``k`` robust sigmas (1.4826 MAD of all departures, per
    axis, at least ``floor_m``). Only sub-scenes with ``CHECK_MIN_PER_SCENE`` checks or more
    can flag one, and only when such sub-scenes hold ``CHECK_MIN_JUDGED`` checks in all (the
    robust sigma needs them).
    """
    scene, err = np.asarray(scene), np.asarray(error_m, dtype=float)
    dev = np.zeros_like(err)
    judged = np.zeros(len(err), dtype=bool)
    for s in np.unique(scene):
        own = scene == s
        if own.sum() >= CHECK_MIN_PER_SCENE:
            dev[own] = err[own] - np.median(err[own], axis=0)
            judged |= own
    if judged.sum() < CHECK_MIN_JUDGED:
        return np.zeros(len(err), dtype=bool)
    d = dev[judged]
    sigma = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return judged & np.any(np.abs(dev) > k * np.maximum(sigma, floor_m), axis=1)
