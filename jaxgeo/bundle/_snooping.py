"""Data snooping: Baarda's w-test with redundancy numbers, iterated (host side).

After each (robust) solve every observation gets its standardised residual
``w = e / (sigma sqrt(r))`` (``e`` the residual, ``r`` its redundancy number in the weighted
normal equations); those above ``blunder_k`` are flagged. Unless told otherwise
(``SolverConfig.remove_blunders``) the worst flagged observations are removed and the block
re-solved, until none is flagged: with least squares one observation per round (a gross error
spreads into its neighbours' residuals; but see :data:`BATCH_RATIO` for blocks with many
observations per parameter), with a robust loss every flagged observation within a factor 2 of
the worst (the robust solution already isolates them; rounds repeat for the
smaller ones). An image observation of a point without ground coordinates (tie or check) whose
removal leaves the point in fewer than two images takes the point's other observations with it
(a two-ray point's gross error cannot be told from its partner: the point group is removed,
with its height-only ground observation if it has one; such an observation flagged takes its
point's rays with it).
Snooping never removes more than a small share of the data (:data:`MAX_REMOVED_FRACTION`):
beyond it the misfit is the model's, and it is declared, not cut away.
Removal is a weight (``REMOVED_WEIGHT`` of the solve), with the measurement moved to the last
solution's prediction (a point left with removed observations only then stays where it was and
costs nothing), so that the compiled solve is reused; the residuals reported are against the
measurements as given. A GCP's coordinates are removed only where the point is measured in two
images or more (it then becomes a tie point); otherwise they are flagged only. When every ray of
a GCP is flagged, the rays agree with each other and the coordinates do not: the coordinates
are removed instead (a height-only ground observation, a DEM height on a tie, is not a GCP:
its point's rays are removed as a tie point's).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._runtime.arrays import device_array
from ..lsq import RESULTS, Solution, SolverConfig, initial_unknowns, solve_kept
from ..lsq.internal import BLUNDER_K, DEFAULT_SOLVER
from ._prepare import Prepared
from ._prepare.checks import listing
from ._report import enu_errors as enu

DEFAULT_ROUNDS = SolverConfig().snooping_rounds
MAX_REMOVED_FRACTION = 0.2
"""Snooping removes at most ``max(1, floor(MAX_REMOVED_FRACTION n))`` of the ``n`` GCPs, of the
``n`` GCPs measured in any one image (its ray there or the coordinates), and of the ``n``
observations of any one image (a point removed whole counts once, shared among its images),
and never all of them (:func:`removal_cap`, :func:`over_limits`). A round
that would remove more is not done: so many "gross errors" are a model that does not fit (two
RPC files swapped, a model of another image, a bias model that cannot absorb the error), not
something to cut away; the observations stay, and :func:`snooping_verdict` says so
(:class:`~._errors.PoorFitWarning`, ``jaxgeo adjust`` exit 3)."""
BATCH_RATIO = 200
"""Least squares removes one observation per round (a gross error spreads into the others'
residuals through the shared parameters), a robust loss the flagged ones within
``ROBUST_FRACTION`` of the worst, unless there are this many image observations per camera
parameter or more (e.g. a pair with thousands of ties): the spread through the parameters is
then negligible, and every flagged point loses its worst observation in the same round (at most
one per point: within a point a gross error spreads into the other rays)."""
DETECT_IRLS = 5
"""Reweighted solves at most in the first solve of a block with ``BATCH_RATIO`` observations per
parameter or more, while the gross errors are all still in: they stand out after a few (the
same ones are flagged after 5 as after 20 on a pair with 20 000 ties and 1 % gross errors),
while on such data the weights settle only once they are gone; the re-solves after a removal
get the configured ``irls_iterations``, and so does a first solve that flags nothing but did
not settle (it is repeated)."""
ROBUST_FRACTION = 0.5
"""With a robust loss, a round removes the flagged observations with ``|w|`` at least this
fraction of the largest."""


def standardized(sol: Solution) -> tuple[np.ndarray, np.ndarray]:
    """``(image (M, 2), ground (c, 3))`` standardised residuals in problem order (NaN where the
    redundancy number is ~0: the observation is not controlled by the others)."""
    out = []
    for r, red in (
        (sol.residuals_image, sol.redundancy_image),
        (sol.residuals_ground, sol.redundancy_ground),
    ):
        r, red = np.asarray(r), np.asarray(red)
        with np.errstate(invalid="ignore", divide="ignore"):
            out.append(np.where(red > 1e-10, r / np.sqrt(np.maximum(red, 1e-300)), np.nan))
    return out[0], out[1]


def _worst_per_point(w: np.ndarray, point: np.ndarray, cut: float) -> np.ndarray:
    """The observations with ``w >= cut`` that have the largest ``w`` of their point (one per
    point: within a point a gross error spreads into the other rays)."""
    best = np.full(point.max(initial=-1) + 1, -np.inf)
    np.maximum.at(best, point, w)
    pick = (w >= cut) & (w >= best[point])
    first = np.zeros_like(pick)  # ties within a point: the first one
    idx = np.flatnonzero(pick)
    _, keep = np.unique(point[idx], return_index=True)
    first[idx[keep]] = True
    return first


def _largest(w: np.ndarray) -> np.ndarray:
    return np.max(np.abs(np.nan_to_num(w)), axis=1) if w.size else np.zeros(w.shape[0])


def solve_settings(solver: SolverConfig) -> SolverConfig:
    """``solver`` with the fields the compiled solve does not use at their defaults (one
    compilation whatever the snooping settings)."""
    return dataclasses.replace(
        solver, blunder_k=BLUNDER_K, remove_blunders=True, snooping_rounds=DEFAULT_ROUNDS
    )


_solve = solve_kept
"""The solve of every round (:func:`jaxgeo.lsq.solve_kept`: compiled and traced once per
structure, across runs too; the runtime decides how)."""


def removal_cap(n: int) -> int:
    """How many of ``n`` GCPs (or of one image's ``n`` observations) snooping may remove:
    ``max(1, floor(MAX_REMOVED_FRACTION n))``, and never all of them."""
    return min(max(1, int(MAX_REMOVED_FRACTION * n + 1e-9)), max(n - 1, 0))


@dataclasses.dataclass(frozen=True)
class _Layout:
    """What the limits count, in problem order: per image observation its image (index into
    ``names``) and point; per ground observation whether it is a GCP's."""

    names: tuple[str, ...]
    image: np.ndarray
    point: np.ndarray
    gcp_row: np.ndarray
    ground_point: np.ndarray
    point_ids: tuple[str, ...]


def _layout(setup: Prepared) -> _Layout:
    problem = setup.problem
    names = tuple(setup.image_index)
    lookup = {where: i for i, where in enumerate(setup.image_index.values())}
    parts = []
    for ob in problem.images:  # per block of the slot's group, its image (vectorised)
        table = np.array(
            [
                lookup.get((ob.group, k, ob.slot), -1)
                for k in range(problem.groups[ob.group].n_blocks)
            ]
        )
        parts.append(table[np.asarray(ob.block, dtype=int)])
    image = np.concatenate([*parts, np.zeros(0, int)])
    role = dict(zip(setup.point_ids, setup.point_role, strict=True))
    gw = np.asarray(problem.ground.weight)
    gcp_row = np.array([role[p] == "gcp" for p in setup.ground_ids], dtype=bool).reshape(-1)
    gcp_row &= np.any(gw > 0, axis=1) if gw.size else gcp_row
    return _Layout(
        names,
        image,
        np.asarray(problem.structure.obs_point),
        gcp_row,
        np.asarray(problem.ground.point),
        setup.point_ids,
    )


def over_limits(setup: Prepared, drop_image: np.ndarray, drop_ground: np.ndarray) -> list[str]:
    """Why removing the image observations ``drop_image`` (M,) and ground observations
    ``drop_ground`` (c,) (problem order) is more than snooping may remove: more than
    :func:`removal_cap` of the GCPs (a GCP is cut when its coordinates go or all its rays do),
    of the GCPs of one image (a GCP no longer controls an image when its ray in it or its
    coordinates go), or of the observations of one image (a point removed whole, all its
    rays, counts as one gross error shared among its images). Empty when within the limits."""
    lay = _layout(setup)
    drop_image, drop_ground = np.asarray(drop_image, bool), np.asarray(drop_ground, bool)
    reasons = []
    gcp_points = np.unique(lay.ground_point[lay.gcp_row])
    rays = np.bincount(lay.point, minlength=len(lay.point_ids))
    gone = np.bincount(lay.point[drop_image], minlength=len(lay.point_ids))
    if gcp_points.size:
        coords_gone = np.zeros(len(lay.point_ids), dtype=bool)
        coords_gone[lay.ground_point[lay.gcp_row & drop_ground]] = True
        cut = coords_gone.copy()
        cut[gcp_points[(rays[gcp_points] > 0) & (gone[gcp_points] >= rays[gcp_points])]] = True
        n_cut, cap = int(cut.sum()), removal_cap(gcp_points.size)
        if n_cut > cap:
            ids = [lay.point_ids[j] for j in np.flatnonzero(cut)]
            reasons.append(
                f"{n_cut} of the {gcp_points.size} GCPs ({listing(ids, 8)}; at most {cap})"
            )
        # per image: a GCP whose ray in it (or whose coordinates) go no longer controls it
        is_gcp = np.isin(lay.point, gcp_points)
        for k, name in enumerate(lay.names):
            mine = (lay.image == k) & is_gcp
            lost = mine & (drop_image | coords_gone[lay.point])
            n, d = int(mine.sum()), int(lost.sum())
            if d > removal_cap(n) and not (n_cut > cap and d == n_cut):
                ids = [lay.point_ids[j] for j in lay.point[lost]]
                reasons.append(
                    f"{d} of the {n} GCPs of image {name!r} (their ray in it or their "
                    f"coordinates: {listing(ids, 8)}; at most {removal_cap(n)})"
                )
    # a point removed as a whole (its gross error cannot be told from its partner rays) counts
    # as one gross error, shared among its images; a ray removed on its own counts as one
    whole = gone[lay.point] >= rays[lay.point]
    share = np.where(whole, 1.0 / np.maximum(rays[lay.point], 1), 1.0) * drop_image
    for k, name in enumerate(lay.names):
        mine = lay.image == k
        n, d = int(mine.sum()), float(np.sum(share[mine]))
        if d > removal_cap(n) + 1e-9:
            reasons.append(
                f"{d:g} of the {n} observations of image {name!r} (at most {removal_cap(n)}; "
                "a point removed whole counts once, shared among its images)"
            )
    return reasons


def next_removal(
    setup: Prepared,
    sol: Solution,
    removed_image: np.ndarray,
    removed_ground: np.ndarray,
    solver: SolverConfig = DEFAULT_SOLVER,
    kept: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The observations the next snooping round removes after ``sol`` (masks in problem order,
    see the module docstring), ``None`` when none is flagged. ``kept``: ``(image, ground)``
    masks of observations that stay whatever their residual (beyond the limits)."""
    problem = setup.problem
    point = np.asarray(problem.structure.obs_point)
    rem_i, rem_g = np.asarray(removed_image, bool), np.asarray(removed_ground, bool)
    keep_i, keep_g = (np.zeros_like(rem_i), np.zeros_like(rem_g)) if kept is None else kept
    gw = np.asarray(problem.ground.weight)
    gpts = np.asarray(problem.ground.point)
    n_points = problem.structure.n_points
    # control in plan: a height-only prior (a DEM height on a tie) does not make a GCP, whose
    # rays could all disagree with its coordinates
    gcp_point = np.zeros(n_points, dtype=bool)
    gcp_point[gpts[np.any(gw[:, :2] > 0, axis=1)]] = True
    rays = np.bincount(point, minlength=n_points)
    removable_g = rays[gpts] >= 2
    height_only = ~np.any(gw[:, :2] > 0, axis=1) & (gw[:, 2] > 0)
    w_i, w_g = (_largest(w) for w in standardized(sol))
    w_i = np.where(rem_i | keep_i, 0.0, w_i)
    w_g = np.where(rem_g | keep_g | ~removable_g, 0.0, w_g)
    worst = max(w_i.max(initial=0.0), w_g.max(initial=0.0))
    if not worst > solver.blunder_k:
        return None
    if _at_scale(problem):
        # many rays per parameter: points are all but independent, and one's gross error
        # does not show in another's w: every flagged point loses its worst ray at once
        cut = solver.blunder_k
        pick_i, pick_g = _worst_per_point(w_i, point, cut), w_g >= cut
    elif solver.loss == "l2":
        pick_i, pick_g = w_i >= worst, w_g >= worst
    else:
        cut = max(solver.blunder_k, ROBUST_FRACTION * worst)
        pick_i, pick_g = w_i >= cut, w_g >= cut
    # every ray of a GCP flagged: the rays agree with each other, its coordinates do not
    for p in np.unique(point[pick_i]):
        own = (point == p) & ~rem_i
        if gcp_point[p] and own.sum() >= 2 and np.all(pick_i[own]):
            pick_i &= ~own
            pick_g |= (gpts == p) & removable_g
    # a height-only ground observation (a DEM height on a tie) flagged: its rays disagree
    # with it, and without it they (near-parallel along a strip) leave the point
    # undetermined: the point goes as a whole
    pick_i |= np.isin(point, gpts[pick_g & height_only]) & ~rem_i
    # a point without (kept) ground coordinates left in < 2 images goes as a whole
    left = np.bincount(point[~(rem_i | pick_i)], minlength=n_points)
    controlled = gcp_point.copy()  # a GCP whose coordinates go is a tie point now
    controlled[gpts[rem_g | pick_g]] = False
    short = (left < 2) & ~controlled
    hit = np.zeros(short.size, dtype=bool)
    hit[point[pick_i]] = True
    whole = np.flatnonzero(short & hit)
    pick_i |= np.isin(point, whole)
    # with its height prior, if any (a DEM height on a tie): a point kept by that alone at
    # full weight, its rays at the removed weight, would be undetermined in plan
    pick_g |= np.isin(gpts, whole) & removable_g
    return pick_i & ~keep_i, pick_g & ~keep_g


def _at_scale(problem) -> bool:
    m = int(np.asarray(problem.structure.obs_point).shape[0])
    return m >= BATCH_RATIO * max(problem.structure.n_params, 1)


def snooping_verdict(
    setup: Prepared,
    sol: Solution,
    removed: tuple[np.ndarray, np.ndarray] | None = None,
    solver: SolverConfig = DEFAULT_SOLVER,
) -> list[str]:
    """Whether snooping stopped (or, with ``remove_blunders=False``, would stop) at its limits
    after ``sol``: the reasons of :func:`over_limits` for the removals done (``removed``, problem
    order) plus the next round's; empty when the flagged observations are within the limits.
    So many gross errors are a model that does not fit (:class:`~._errors.PoorFitWarning`)."""
    problem = setup.problem
    m, c = problem.structure.obs_point.shape[0], int(problem.ground.point.shape[0])
    rem_i, rem_g = (np.zeros(m, bool), np.zeros(c, bool)) if removed is None else removed
    ok = (RESULTS.successful, RESULTS.not_converged)
    if not any(bool(sol.result == r) for r in ok):
        return []
    pick = next_removal(setup, sol, rem_i, rem_g, solver)
    if pick is None:
        return []
    return over_limits(setup, np.asarray(rem_i) | pick[0], np.asarray(rem_g) | pick[1])


def snoop(
    setup: Prepared,
    solver: SolverConfig = DEFAULT_SOLVER,
    progress: Callable[[str], None] | None = None,
) -> tuple[Solution, np.ndarray, np.ndarray, int]:
    """Solve, then remove gross errors and re-solve (see the module docstring).

    Returns ``(solution, removed image observations (M,), removed ground observations (c,),
    rounds)``, the masks in problem order. Stops early when a solve fails (singular,
    non-finite), before a removal that would leave unknowns undetermined (those observations
    stay, flagged only), and before one beyond the limits (:func:`over_limits`: more than
    ``max(1, 20 %)`` of the GCPs, of one image's GCPs or of one image's observations): GCP
    observations beyond them stay, flagged, and the other gross errors are still removed; any
    other excess stops it; :func:`snooping_verdict` then says the models do not fit.
    ``progress`` is called with a line of text before each solve.
    """
    say = progress if progress is not None else (lambda line: None)
    problem = setup.problem
    compiled = solve_settings(solver)
    m, c = problem.structure.obs_point.shape[0], int(problem.ground.point.shape[0])
    rem_i, rem_g = np.zeros(m, dtype=bool), np.zeros(c, dtype=bool)
    xy0 = np.concatenate([np.asarray(ob.xy) for ob in problem.images] + [np.zeros((0, 2))])
    w_xy = np.concatenate([np.asarray(ob.weight) for ob in problem.images] + [np.zeros(0)])
    g0 = np.asarray(problem.ground.lonlath)
    xy, g = xy0.copy(), g0.copy()
    point, gpts = np.asarray(problem.structure.obs_point), np.asarray(problem.ground.point)
    gcp_rows = _layout(setup).gcp_row
    limit = solver.snooping_rounds if solver.remove_blunders else 0
    full = device_array(solver.irls_iterations)
    at_scale = _at_scale(problem)
    brief = bool(limit) and solver.loss != "l2" and at_scale  # a short first reweighting
    irls = device_array(DETECT_IRLS) if brief else full
    cold = (initial_unknowns(problem), device_array(np.ones(m)), device_array(np.ones(c)))

    def warm(last: Solution):
        # at scale a removal barely moves the solution: the re-solve goes on from the last one
        # (its weights too). A small block starts afresh: a gross error there biased the last
        # solution, whose robust weights would keep good observations out (Cauchy is not convex)
        return (last.unknowns, last.weight_image, last.weight_ground) if at_scale else cold

    st = problem.structure
    say(
        f"solving: {m} image observations, {st.n_points} points, {st.n_params} parameters "
        f"({solver.loss} loss; a block of a new shape is compiled first, up to a minute)"
    )

    def run(how: tuple) -> Solution:
        prob, removed_i, removed_g, limit, start = how
        return _solve(
            prob,
            compiled,
            removed_image=removed_i,
            removed_ground=removed_g,
            irls_limit=limit,
            start=start,
        )

    # how the current solution was solved: run again, the same program on the same inputs gives
    # the same solution (bitwise on a CPU; a GPU's reductions are not bitwise repeatable: 1e-10
    # apart on an H200), so that it need not be held through a re-solve (21 MB at 200 000
    # observations; its start, the last solution's unknowns and weights, is a quarter of that)
    how = (problem, rem_i, rem_g, irls, cold)
    sol = run(how)
    rounds = 0
    # a robust solve whose weights still move (not_converged) is snooped on: removing the gross
    # errors is what lets the reweighting settle
    ok = (RESULTS.successful, RESULTS.not_converged)
    # GCP observations beyond the limits stay (flagged: snooping_verdict declares them); the
    # other gross errors are still removed
    gcp_ray = np.isin(point, gpts[gcp_rows])
    kept_i, kept_g = np.zeros(m, dtype=bool), np.zeros(c, dtype=bool)
    while rounds < limit and any(bool(sol.result == r) for r in ok):
        pick = next_removal(setup, sol, rem_i, rem_g, solver, kept=(kept_i, kept_g))
        if pick is None:
            break
        pick_i, pick_g = pick
        if over_limits(setup, rem_i | pick_i, rem_g | pick_g):
            gcp_part_i = pick_i & gcp_ray & ~(rem_i | kept_i)
            gcp_part_g = pick_g & gcp_rows & ~(rem_g | kept_g)
            if not (gcp_part_i.any() or gcp_part_g.any()):
                break  # so many "gross errors" are a misfit: they stay (snooping_verdict)
            kept_i, kept_g = kept_i | gcp_part_i, kept_g | gcp_part_g
            continue  # the next pick leaves them out
        new_i, new_g = pick_i & ~rem_i, pick_g & ~rem_g
        if not (new_i.any() or new_g.any()):
            break  # flagged, but nothing left to remove (e.g. a GCP's coordinates, gone)
        say(
            f"snooping round {rounds + 1}: removing {int(new_i.sum())} image and "
            f"{int(new_g.sum())} ground observations flagged as gross errors, re-solving"
        )
        # removed measurements sit at the last prediction: (project - xy) = r sigma
        xy_try, g_try = xy.copy(), g.copy()
        xy_try[new_i] = xy0[new_i] + np.asarray(sol.residuals_image)[new_i] / w_xy[new_i, None]
        g_try[new_g] = np.asarray(sol.ground)[np.asarray(problem.ground.point)[new_g]]
        moved = eqx.tree_at(
            lambda p: p.ground.lonlath, problem.with_xy(jnp.asarray(xy_try)), jnp.asarray(g_try)
        )
        tried_how = (moved, rem_i | pick_i, rem_g | pick_g, full, warm(sol))
        del sol
        tried = run(tried_how)
        if bool(tried.result == RESULTS.undetermined):
            # these removals would leave unknowns undetermined (the control of an image): they
            # stay, flagged only, and the snooping stops here, at the last solution
            del tried
            sol = run(how)
            break
        sol, how, xy, g = tried, tried_how, xy_try, g_try
        rem_i, rem_g = rem_i | pick_i, rem_g | pick_g
        problem = moved
        rounds += 1
    if brief and not rounds and bool(sol.result == RESULTS.not_converged):
        # the reweighting had the snooping's short budget: the answer gets the whole one
        how = (problem, rem_i, rem_g, full, warm(sol))
        del sol
        sol = run(how)
    if rounds:  # residuals against the measurements as given
        r_img = np.asarray(sol.residuals_image) + (xy - xy0) * w_xy[:, None]
        pts = np.asarray(sol.ground)[np.asarray(problem.ground.point)]
        r_gnd = np.asarray(enu(pts, g0)) * np.asarray(problem.ground.weight)
        sol = eqx.tree_at(
            lambda s: (s.residuals_image, s.residuals_ground),
            sol,
            (jnp.asarray(r_img), jnp.asarray(r_gnd)),
        )
    return sol, rem_i, rem_g, rounds
