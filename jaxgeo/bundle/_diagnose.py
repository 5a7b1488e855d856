"""Diagnosis on the host: which parameters or points the normal equations do not determine.

A ground point is undetermined when its 3x3 block ``V`` (image rays plus ground observations) is
singular: one ray, parallel rays. Camera parameters are undetermined when the reduced camera
system ``S = U - W V^-1 W^T`` is singular: the eigenvectors of its (Jacobi-scaled) null space
name them, e.g. a common shift of all images with no GCP.
"""

from __future__ import annotations

import dataclasses
import warnings

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..io.internal import dem_against_ties
from ..lsq import Band, Problem, blocks_at, initial_unknowns, unit_scales
from ..lsq.internal import reduced_system
from ..models import AbstractSensorModel

SINGULAR_RTOL = 1e-10
"""Eigenvalues below this fraction of the largest (after unit-diagonal scaling) are zero."""


@eqx.filter_jit
def _normal_matrices(problem: Problem, y, loss: str, loss_scale: float):
    _, blocks = blocks_at(problem, unit_scales(problem), y, loss, loss_scale)
    big_s, _ = reduced_system(blocks, problem.structure, 0.0)
    if isinstance(big_s, Band):  # diagnostics only: the dense matrix, dummy row last
        big_s = jnp.pad(big_s.todense(), ((0, 1), (0, 1)))
    return blocks.v, big_s, blocks.w


def _singular_points(v: np.ndarray, rtol: float) -> list[int]:
    """Points whose (unit-diagonal scaled) 3x3 block is singular, vectorised."""
    if v.shape[0] == 0:
        return []
    d = np.diagonal(v, axis1=1, axis2=2)
    ok = np.all(d > 0, axis=1) & np.all(np.isfinite(v), axis=(1, 2))
    safe = np.where(ok[:, None], d, 1.0)
    scaled = np.where(ok[:, None, None], v / np.sqrt(safe[:, :, None] * safe[:, None, :]), 1.0)
    scaled = np.where(ok[:, None, None], scaled, np.eye(3))
    ev = np.linalg.eigvalsh(scaled)
    bad = ~ok | (ev[:, 0] < rtol * ev[:, -1])
    return [int(j) for j in np.flatnonzero(bad)]


class Direction(eqx.Module):
    """An undetermined direction of the camera parameters (a null vector of ``S``).

    ``params`` (N,): the parameter combination (largest component 1, in parameter units);
    ``point_motion_m`` (3,): RMS over the points of the east, north, up motion (m) that goes
    with a unit step along it (the points absorbing it; zeros when nothing moves).
    """

    params: np.ndarray
    point_motion_m: np.ndarray


def undetermined(
    problem: Problem,
    y=None,
    *,
    loss: str = "l2",
    loss_scale: float = 3.0,
    rtol: float = SINGULAR_RTOL,
) -> tuple[list[int], list[int]]:
    """``(parameter indices, point indices)`` not determined at ``y`` (default: the start).

    ``y = (z, u)`` in the solver's variables with unit scales (``theta - theta0`` and
    metres); ``loss``, ``loss_scale`` as in the solve (:class:`jaxgeo.lsq.SolverConfig`).
    """
    y = y if y is not None else initial_unknowns(problem)
    v, big_s, _ = (np.asarray(x) for x in _normal_matrices(problem, y, loss, float(loss_scale)))
    bad_points = _singular_points(v, rtol)
    n = problem.structure.n_params
    if bad_points or n == 0:
        return [], bad_points
    s = big_s[:n, :n]
    d = np.diag(s).copy()
    zero = [i for i in range(n) if not d[i] > 0]
    if zero:
        return zero, []
    ev, vec = np.linalg.eigh(s / np.sqrt(np.outer(d, d)))
    null = ev < rtol * ev[-1]
    if not np.any(null):
        return [], []
    weight = np.sum(vec[:, null] ** 2, axis=1)
    return [int(i) for i in np.flatnonzero(weight > 1e-2)], []


def directions(
    problem: Problem,
    y=None,
    *,
    loss: str = "l2",
    loss_scale: float = 3.0,
    rtol: float = SINGULAR_RTOL,
    weakest: bool = False,
) -> list[Direction]:
    """The undetermined directions of the camera parameters at ``y`` (arguments as
    :func:`undetermined`), each with the point motion that absorbs it; empty when ``S`` is
    regular (or a point block is singular: :func:`undetermined` names those), unless
    ``weakest``: then the least determined direction (a nearly singular ``S``, e.g. a shift
    that only the terrain relief of the tie points determines)."""
    y = y if y is not None else initial_unknowns(problem)
    v, big_s, w = (np.asarray(x) for x in _normal_matrices(problem, y, loss, float(loss_scale)))
    st = problem.structure
    n = st.n_params
    if n == 0 or _singular_points(v, rtol):
        return []
    s = big_s[:n, :n]
    d = np.diag(s).copy()
    d = np.where(d > 0, d, 1.0)
    ev, vec = np.linalg.eigh(s / np.sqrt(np.outer(d, d)))
    null = ev < rtol * ev[-1]
    if weakest and not null.any():
        null[0] = True
    out = []
    for k in np.flatnonzero(null):
        c = vec[:, k] / np.sqrt(d)
        c = c / c[np.argmax(np.abs(c))]
        c[np.abs(c) < 1e-9] = 0.0
        # the points follow: dp = -V^-1 sum_obs W^T c (W: (M, P, 3))
        cpad = np.concatenate([c, [0.0]])[np.asarray(st.obs_params)]
        rhs = np.zeros((st.n_points, 3))
        np.add.at(rhs, np.asarray(st.obs_point), np.einsum("mpj,mp->mj", w, cpad))
        dp = -np.linalg.solve(v, rhs[..., None])[..., 0] if st.n_points else rhs
        motion = np.sqrt(np.mean(dp**2, axis=0)) if st.n_points else np.zeros(3)
        out.append(Direction(c, motion))
    return out


def explain(direction: Direction, param_names, limit: int = 4) -> str:
    """``direction`` in words: its largest parameters and what absorbs it, e.g. ``aft.bias.
    shift_px[1] (+1) trades against the tie point heights (1 unit moves them 2.1 m up, RMS):
    along-track parallax``."""
    c = np.asarray(direction.params)
    order = [i for i in np.argsort(-np.abs(c)) if abs(c[i]) >= 1e-3][:limit]
    combo = " ".join(f"{c[i]:+.3g} {param_names[i]}" for i in order)
    e, nn, u = (float(x) for x in direction.point_motion_m)
    horiz = float(np.hypot(e, nn))
    if max(horiz, u) < 1e-6:
        what = "no observation sees it (the parameters trade against each other)"
    elif u > 3.0 * horiz:
        what = (
            f"trades against the tie point heights (one unit moves them {u:.3g} m up or down, "
            "RMS): a shift along the epipolar direction is a height change of the points "
            "(along-track parallax)"
        )
    elif horiz > 3.0 * u:
        what = (f"trades against the point positions (one unit moves them {horiz:.3g} m "
                "horizontally, RMS): a common shift of the block")  # fmt: skip
    else:
        what = (f"trades against the point positions ({horiz:.3g} m horizontally, {u:.3g} m in "
                "height per unit, RMS)")  # fmt: skip
    return f"{combo} {what}"


# --- the geometry of a block without GCPs ------------------------------------------------------
# With GCPs, a model that does not belong to its image is found by the fit (snooping's limits,
# s0). Tie points alone fit almost any pair of models: two swapped RPCs of a triplet leave
# s0 0.41 against 0.35, the affine biases absorb the rest, and the ties come out hundreds of
# metres below the terrain. What shows it is the geometry: heights the models (or the DEM)
# were never made for, rays that do not meet, biases far beyond the user's priors.

HEIGHT_MARGIN_M = 50.0
"""Tie heights count as outside a validity range (the models' offset +- scale, the DEM's
heights at the ties) beyond this margin (m), or ``HEIGHT_MARGIN_FRACTION`` of its span if more."""
HEIGHT_MARGIN_FRACTION = 0.1
OUTSIDE_FRACTION = 0.2
"""An image is named when more than this share of its tie points lies outside (beyond a
share of gross errors snooping may remove: :data:`~._snooping.MAX_REMOVED_FRACTION`)."""
RAY_MISS_PX = 50.0
"""Rays do not meet when, with the models as given (before any bias is adjusted), the median
over the tie points of a set of images of their largest ray residual at the intersection is
above this (px): beyond the relative error of vendor RPCs (tens of px for Cartosat-1)."""
RAY_SAMPLE = 256
"""Tie points intersected per set of images for :data:`RAY_MISS_PX` (evenly spaced; one
compiled intersection per number of images)."""
PRIOR_K = 5.0
"""A bias parameter whose standardised prior residual ``(theta - theta0) / (sigma_prior
sqrt(r))`` (``r`` its redundancy number) exceeds this is far beyond the user's prior."""


def ties_only(setup) -> bool:
    """Whether no ground observation fixes a point in plan (tie points, and at most DEM
    heights of ties): the block's geometry rests on the models and the priors alone."""
    gw = np.asarray(setup.problem.ground.weight)
    return not (gw.size and np.any(gw[:, :2] > 0))


def _kept_rays(setup, removed):
    from ._snooping import _layout

    lay = _layout(setup)
    keep = np.ones(lay.point.shape[0], bool)
    if removed is not None:
        keep &= ~np.asarray(removed[0], bool)
    return lay, keep


def _outside(h: np.ndarray, lo: float, hi: float) -> np.ndarray:
    margin = max(HEIGHT_MARGIN_M, HEIGHT_MARGIN_FRACTION * (hi - lo))
    return (h < lo - margin) | (h > hi + margin) | ~np.isfinite(h)


def height_reasons(setup, ground: np.ndarray, removed=None) -> list[str]:
    """Why the tie heights ``ground[:, 2]`` (m, per point) do not belong to the models or the
    DEM: per image, more than :data:`OUTSIDE_FRACTION` of its tie points (with two kept rays or
    more) outside its model's validity heights; more than that share of all outside the DEM's
    heights at the ties (its height observations), each range widened by the margin
    (:data:`HEIGHT_MARGIN_M`). Empty when they fit."""
    lay, keep = _kept_rays(setup, removed)
    n_points = len(lay.point_ids)
    rays = np.bincount(lay.point[keep], minlength=n_points)
    tie = np.array([r == "tie" for r in setup.point_role]) & (rays >= 2)
    h = np.asarray(ground, float)[:, 2]
    groups = setup.problem.groups
    models = setup.image_models(groups, tuple(g.theta0 for g in groups))
    bad, ranges = [], {}
    for k, name in enumerate(lay.names):
        model = models[name]
        rpc = model.base_rpc() if isinstance(model, AbstractSensorModel) else None
        mine = np.zeros(n_points, bool)
        mine[lay.point[keep & (lay.image == k)]] = True
        mine &= tie
        if rpc is None or not mine.any():
            continue
        off, scale = float(rpc.ground_offset[2]), abs(float(rpc.ground_scale[2]))
        out = _outside(h[mine], off - scale, off + scale)
        if out.mean() > OUTSIDE_FRACTION:
            bad.append((name, out.mean()))
            ranges[name] = (off - scale, off + scale)
    reasons = []
    if bad:
        pct = np.percentile(h[tie], [5, 95])
        span = {f"{lo:.0f}..{hi:.0f} m" for lo, hi in ranges.values()}
        reasons.append(
            f"the tie points' heights (p5..p95 {pct[0]:.0f}..{pct[1]:.0f} m) leave the models' "
            f"validity range ({', '.join(sorted(span))}): "
            + ", ".join(f"{100 * f:.0f} % of the ties of image {n!r}" for n, f in bad)
        )
    gw = np.asarray(setup.problem.ground.weight)
    dem_rows = (gw[:, 2] > 0) & ~np.any(gw[:, :2] > 0, axis=1) if gw.size else np.zeros(0, bool)
    if dem_rows.any():
        pts = np.asarray(setup.problem.ground.point)[dem_rows]
        dem_h = np.asarray(setup.problem.ground.lonlath)[dem_rows, 2]
        sel = tie[pts]
        # before the adjustment (the ties intersected with the given models): a DEM in feet,
        # another datum or place shows in its heights against the ties' own, named
        start = np.asarray(setup.problem.origin, float)[pts[sel], 2]
        why = dem_against_ties(start, dem_h[sel], "the DEM of the tie heights (--dem)")
        if why is not None:
            reasons.append(why)
        if sel.any():
            lo, hi = float(np.min(dem_h[sel])), float(np.max(dem_h[sel]))
            out = _outside(h[pts[sel]], lo, hi)
            if out.mean() > OUTSIDE_FRACTION:
                pct = np.percentile(h[pts[sel]], [5, 95])
                reasons.append(
                    f"{100 * out.mean():.0f} % of the tie points lie outside the DEM's heights "
                    f"{lo:.0f}..{hi:.0f} m at the ties (p5..p95 {pct[0]:.0f}..{pct[1]:.0f} m, "
                    f"in images {', '.join(map(repr, lay.names))})"
                )
    return reasons


def ray_reasons(setup, removed=None) -> list[str]:
    """Sets of images whose rays do not meet with the models as given: the median over (at most
    :data:`RAY_SAMPLE` of) their tie points of the largest ray residual at the intersection
    above :data:`RAY_MISS_PX`, or an intersection that fails. Empty when they meet."""
    from ..intersect import intersect

    lay, keep = _kept_rays(setup, removed)
    problem = setup.problem
    xy = np.concatenate([np.asarray(ob.xy) for ob in problem.images] + [np.zeros((0, 2))])
    groups = problem.groups
    models = setup.image_models(groups, tuple(g.theta0 for g in groups))
    tie = np.array([r == "tie" for r in setup.point_role])
    by_point: dict[int, dict[int, int]] = {}
    for i in np.flatnonzero(keep & tie[lay.point]):
        by_point.setdefault(int(lay.point[i]), {})[int(lay.image[i])] = int(i)
    by_set: dict[tuple[int, ...], list[dict[int, int]]] = {}
    for rows in by_point.values():
        if len(rows) >= 2:
            by_set.setdefault(tuple(sorted(rows)), []).append(rows)
    reasons = []
    for imgs, members in by_set.items():
        n = min(RAY_SAMPLE, len(members))
        pick = np.unique(np.linspace(0, len(members) - 1, n).astype(int))
        # padded with rays that are not there: one shape, one compilation per image count
        pts = np.full((RAY_SAMPLE, len(imgs), 2), np.nan)
        pts[: pick.size] = [[xy[members[j][k]] for k in imgs] for j in pick]
        res = intersect([models[lay.names[k]] for k in imgs], pts, 1.0)
        miss = np.max(np.linalg.norm(np.asarray(res.residuals_px), axis=-1), axis=-1)
        miss = np.where(np.asarray(res.converged), miss, np.inf)[: pick.size]
        med = float(np.median(miss))
        if not med <= RAY_MISS_PX:
            names = ", ".join(repr(lay.names[k]) for k in imgs)
            what = f"{med:.3g} px" if np.isfinite(med) else "no intersection"
            reasons.append(
                f"the rays of images {names} do not meet with the models as given (median "
                f"largest ray residual at the intersection of {len(pick)} of their "
                f"{len(members)} tie points: {what}; above {RAY_MISS_PX:g} px)"
            )
    return reasons


def prior_reasons(setup, sol) -> list[str]:
    """Parameters adjusted far beyond their priors (the user's ``theta0 +- sigma``): the
    standardised prior residual above :data:`PRIOR_K`. Empty without priors or when within."""
    problem = setup.problem
    parts_w, parts_m = [], []
    for w, m, g in zip(problem.prior_weight, problem.prior_mean, problem.groups, strict=True):
        w, m = np.asarray(w), np.asarray(m)
        parts_w.append(w.reshape(-1) if w.shape[1] else np.zeros(g.n_blocks * g.n_params))
        parts_m.append(m.reshape(-1) if m.shape[1] else np.zeros(g.n_blocks * g.n_params))
    wt = np.concatenate([*parts_w, np.zeros(0)])
    if not np.any(wt > 0):
        return []
    mean = np.concatenate([*parts_m, np.zeros(0)])
    theta = np.concatenate([np.asarray(t).reshape(-1) for t in sol.theta] + [np.zeros(0)])
    q = sol.q_params.diagonal() if isinstance(sol.q_params, Band) else np.diagonal(sol.q_params)
    q = np.asarray(q, float)
    z = (theta - mean) * wt
    r = 1.0 - q * wt**2
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(r > 1e-3, z / np.sqrt(np.maximum(r, 1e-3)), 0.0)
    far = np.flatnonzero((wt > 0) & (np.abs(w) > PRIOR_K))
    if far.size == 0:
        return []
    order = far[np.argsort(-np.abs(w[far]))]
    shown = ", ".join(
        f"{setup.param_names[i]} = {theta[i]:.3g} ({abs(w[i]):.3g} sigma of its prior "
        f"{mean[i]:.3g} +- {1.0 / wt[i]:.3g})"
        for i in order[:4]
    )
    more = f" and {order.size - 4} more" if order.size > 4 else ""
    return [
        "the relative orientation is far from the given one: the biases moved beyond "
        f"{PRIOR_K:g} sigma of their priors: {shown}{more}"
    ]


def geometry_verdict(setup, sol, removed=None) -> list[str]:
    """Why the geometry of a block without GCPs (:func:`ties_only`) says its models do not
    belong to their images, after the solve ``sol`` (``removed``: snooping's masks, problem
    order): :func:`height_reasons` of the adjusted tie points, :func:`ray_reasons` of the rays
    with the models as given, :func:`prior_reasons`. Empty when it fits, or with GCPs (the fit
    itself shows it then)."""
    if not ties_only(setup):
        return []
    return [
        *height_reasons(setup, np.asarray(sol.ground), removed),
        *ray_reasons(setup, removed),
        *prior_reasons(setup, sol),
    ]


def geometry_message(reasons: list[str], dem: bool = False) -> str:
    """The :class:`~._errors.PoorFitWarning` text of :func:`geometry_verdict`'s ``reasons``
    (``dem``: the ties had heights from a DEM, which may be the cause)."""
    also = (
        ", or a DEM of tie heights that is not the terrain's (in feet, another datum or place)"
        if dem
        else ""
    )
    return (
        "the tie points do not fit the geometry of the models (a block without GCPs): "
        + "; ".join(reasons)
        + ". Likely cause: a model that does not belong to its image (e.g. two RPC files "
        f"swapped, or a model of another scene){also}; check the models of the images named "
        "(tie points alone fit such models: s0 stays small)."
    )


def checked_geometry(result, removed=None):
    """``result`` (an :class:`~._result.AdjustResult`) with :func:`geometry_verdict`'s
    reasons added to its ``poor_fit`` and warned as :class:`~._errors.PoorFitWarning`
    (``jaxgeo adjust`` exit 3); unchanged when the geometry fits or the solve failed."""
    from ..lsq import RESULTS
    from ._errors import PoorFitWarning

    sol = result.solution
    if not any(bool(sol.result == r) for r in (RESULTS.successful, RESULTS.not_converged)):
        return result
    reasons = geometry_verdict(result.setup, sol, removed)
    if not reasons:
        return result
    gw = np.asarray(result.setup.problem.ground.weight)
    text = geometry_message(reasons, dem=bool(gw.size and np.any(gw[:, 2] > 0)))
    warnings.warn(text, PoorFitWarning, stacklevel=3)
    poor = f"{result.poor_fit} {text}" if result.poor_fit else text
    return dataclasses.replace(result, poor_fit=poor)
