"""Result: the :class:`AdjustResult` of a solved problem, in the user's names (host side).

:func:`make_result` maps the arrays of a :class:`jaxgeo.lsq.Solution` back to image names, point ids
and parameter names, scales the cofactors by ``s0**2``, computes standardised residuals and
blunder flags, and turns the solve's ``result`` into an exception (singular: the undetermined
unknowns named) or a warning (not converged).
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np

from ..io import GroundPoints, Observations
from ..lsq import RESULTS, Band, Solution, SolverConfig
from ..lsq.internal import DEFAULT_SOLVER, INFLATION_MAX, describe, undetermined_unknowns
from ._diagnose import directions, explain, undetermined
from ._errors import S0_WARN, NotConvergedWarning, PoorFitWarning, SingularNormalEquations
from ._prepare import Prepared
from ._report import AccuracyReport, accuracy, project
from ._snooping import MAX_REMOVED_FRACTION, snooping_verdict, standardized


@dataclasses.dataclass(frozen=True)
class AdjustResult:
    """The adjusted block (numpy arrays; sigmas a posteriori, i.e. scaled by ``s0**2``).

    Models: ``models`` image name -> adjusted sensor model; ``blocks`` the user's keys ->
    adjusted models (multi-image models under their tuple key).
    Parameters: ``param_names`` (``image.leaf[index]``), ``params``, ``param_sigma``,
    ``param_cov`` (a dense array; for a banded problem such as a strip, a
    ``scipy.sparse.csr_array`` holding the covariances within the band, between a sub-scene's
    parameters and its neighbours': the others are not computed).
    Points: ``point_ids``, ``point_role`` (gcp / check / tie), ``ground`` ``(n, 3)``
    lon/lat/h, ``ground_sigma_m`` ``(n, 3)`` east/north/up, ``ground_cov_m2`` ``(n, 3, 3)``.
    Observations (in the order given: ``observation_ids``, ``observation_images``):
    ``residuals_px`` ``(m, 2)`` = project(adjusted) - measured, ``standardized`` ``(m, 2)``
    (residual / (sigma sqrt(redundancy number))),
    ``blunders`` ``(m,)`` where ``|standardized| > blunder_k``; ``ground_residuals_m``
    ``(c, 3)`` adjusted - given ENU for the GCPs ``gcp_ids``.
    Gross errors (:mod:`~._snooping`): ``removed`` ``(m,)`` observations removed (``blunders``
    includes them); ``gcp_flagged`` GCPs whose ground coordinates are flagged, ``gcp_removed``
    those removed (the point then adjusted as a tie point), ``gcp_w`` the largest standardised
    residual of each flagged GCP; ``checks_excluded`` check points left out of ``report``
    because an observation of theirs is flagged; ``snooping_rounds`` re-solves.
    Statistics: ``s0``, ``redundancy``, ``cost`` (sum of squared weighted residuals),
    ``converged``, ``message`` (short), ``result`` (:class:`jaxgeo.lsq.RESULTS`), ``num_steps``;
    ``report`` (check points without a flagged observation, tables 2-6 of 000_) or None;
    ``report_all`` (every check point, flagged or not) or None.
    Fit: ``poor_fit`` the :class:`~._errors.PoorFitWarning` message when the observations do not
    fit the models (s0 far above 1, or more gross errors than snooping may remove:
    :func:`~._snooping.snooping_verdict`), else ``""``.
    """

    models: dict[str, Any]
    blocks: dict[Any, Any]
    param_names: tuple[str, ...]
    params: np.ndarray
    param_sigma: np.ndarray
    param_cov: Any
    point_ids: tuple[str, ...]
    point_role: tuple[str, ...]
    ground: np.ndarray
    ground_sigma_m: np.ndarray
    ground_cov_m2: np.ndarray
    observation_ids: tuple[str, ...]
    observation_images: tuple[str, ...]
    residuals_px: np.ndarray
    standardized: np.ndarray
    blunders: np.ndarray
    gcp_ids: tuple[str, ...]
    ground_residuals_m: np.ndarray
    s0: float
    redundancy: int
    cost: float
    converged: bool
    message: str
    result: RESULTS
    num_steps: int
    report: AccuracyReport | None
    setup: Prepared = dataclasses.field(repr=False)
    solution: Solution = dataclasses.field(repr=False)
    removed: np.ndarray | None = None
    gcp_flagged: tuple[str, ...] = ()
    gcp_removed: tuple[str, ...] = ()
    gcp_w: tuple[float, ...] = ()
    checks_excluded: tuple[str, ...] = ()
    snooping_rounds: int = 0
    report_all: AccuracyReport | None = None
    poor_fit: str = ""

    def parameters(self, key: Any) -> dict[str, tuple[float, float]]:
        """``{leaf path: (value, sigma)}`` of one model key (image name or tuple of names)."""
        label = key if isinstance(key, str) else "(" + ", ".join(key) + ")"
        return {
            n[len(label) :]: (float(v), float(s))
            for n, v, s in zip(self.param_names, self.params, self.param_sigma, strict=True)
            if n.startswith(label) and n[len(label) : len(label) + 1] in (".", "[")
        }

    def point(self, pid: str) -> tuple[np.ndarray, np.ndarray]:
        """``(lon/lat/h, sigma ENU m)`` of one point."""
        j = self.point_ids.index(pid)
        return self.ground[j], self.ground_sigma_m[j]


def raise_singular(
    setup: Prepared, params: list[int], points: list[int], when: str = "", how: tuple[str, ...] = ()
):
    """Raise :class:`~._errors.SingularNormalEquations` naming parameters and points (and
    ``how``: the undetermined directions in words, :func:`~._diagnose.explain`)."""
    pnames = [setup.param_names[i] for i in params]
    qnames = [setup.point_ids[j] for j in points]
    # undetermined parameters leave the points they carry undetermined too: name the cause
    what = [f"parameter(s) {', '.join(pnames[:12])}" + (" ..." if len(pnames) > 12 else "")]
    if qnames and not pnames:
        what = [f"ground point(s) {', '.join(map(repr, qnames[:10]))}"]
    directions = "".join(f"; direction {k + 1}: {h}" for k, h in enumerate(how[:4]))
    fix = (
        "fix it with a GCP measured in that image, bias priors (--bias-prior-shift-px S "
        "--bias-prior-matrix M), or tie heights from a DEM (--dem)"
        if pnames
        else "their rays do not intersect: seen in one image only, or along parallel rays, as "
        "when two images are given models of the same view; check that each image has its own "
        "model, or give the points ground coordinates"
    )
    raise SingularNormalEquations(
        f"singular normal equations{when}: not determined: {'; '.join(what)}{directions} ({fix})",
        parameters=pnames,
        points=qnames,
    )


def make_result(
    setup: Prepared,
    sol: Solution,
    observations: Observations,
    ground: GroundPoints | None,
    solver: SolverConfig = DEFAULT_SOLVER,
    removed: tuple[np.ndarray, np.ndarray] | None = None,
    rounds: int = 0,
    throw: bool = True,
) -> AdjustResult:
    """The :class:`AdjustResult` of a solved :class:`~._prepare.Prepared` (``prepare`` +
    :func:`jaxgeo.lsq.solve` with ``solver``, e.g. inside a larger jitted function): raises
    :class:`~._errors.SingularNormalEquations` naming the undetermined unknowns when the result is
    ``RESULTS.undetermined``, warns :class:`~._errors.NotConvergedWarning` if the solve did not
    converge. ``removed``: ``(image (M,), ground (c,))`` masks of the observations removed as
    gross errors (problem order, :func:`~._snooping.snoop`), ``rounds`` its re-solves.

    ``throw=False`` (optimistix' convention): neither raise nor warn when the solve failed; the
    result says so (``converged`` False, ``result``, and ``message`` naming the undetermined
    unknowns)."""
    problem = setup.problem
    converged, message = describe(sol.result)
    s0 = float(sol.s0)
    if bool(sol.result == RESULTS.undetermined):
        masks = undetermined_unknowns(
            problem, sol.q_params, sol.inflation_params, sol.inflation_points
        )
        bad_params, bad_points = (np.flatnonzero(np.asarray(m)).tolist() for m in masks)
        # the null space, where the Cholesky factorisation failed or no parameter stood out
        # (points are left open by their own rays or by undetermined parameters, which a
        # factorisation of a singular matrix that ran to the end need not show), of the
        # least-squares normal equations: what is determined is the geometry's, and a robust
        # loss's Newton model has negative curvature where residuals are large (every point's
        # block, once a solve has drifted along the null space for its 100 steps)
        if not bad_params or not np.all(np.isfinite(np.asarray(sol.inflation_params))):
            more_params, more = undetermined(problem, _final_y(problem, sol), loss="l2")
            bad_params, bad_points = more_params, (more if more else bad_points)
        how = ()
        if bad_params and not bad_points:
            found = directions(
                problem,
                _final_y(problem, sol),
                loss=solver.loss,
                loss_scale=solver.loss_scale,
                rtol=1.0 / INFLATION_MAX,
                weakest=True,
            )
            how = tuple(explain(d, setup.param_names) for d in found)
        try:
            raise_singular(setup, bad_params, bad_points, how=how)
        except SingularNormalEquations as err:
            if throw:
                raise
            message = str(err)
    if not converged and throw:
        warnings.warn(
            f"bundle adjustment did not converge ({message}) after {int(sol.num_steps)} steps; "
            f"returning the last state (cost {float(sol.cost):.6g}, s0 {s0:.4g})",
            NotConvergedWarning,
            stacklevel=3,
        )
    out = _result(setup, sol, (converged, message), solver, observations, ground, removed)
    reasons = snooping_verdict(setup, sol, removed, solver)
    plain = plain_s0(sol, removed)
    poor = ""
    if reasons or (np.isfinite(plain) and plain > S0_WARN):
        poor = poor_fit_message(out, plain, reasons, observations, ground)
        warnings.warn(poor, PoorFitWarning, stacklevel=3)
    return dataclasses.replace(out, snooping_rounds=int(rounds), poor_fit=poor)


def plain_s0(sol: Solution, removed=None) -> float:
    """s0 of the least-squares residuals (no robust weights) of the observations kept: the fit
    a robust loss would hide (Cauchy's weighted cost stays near ``c^2`` per observation
    however far off the model is)."""
    r_i, r_g = np.asarray(sol.residuals_image), np.asarray(sol.residuals_ground)
    red = int(sol.redundancy)
    if removed is not None:
        r_i, r_g = r_i[~np.asarray(removed[0])], r_g[~np.asarray(removed[1])]
        w_i = standardized(sol)[0][~np.asarray(removed[0])]
        # observations flagged but kept (--keep-blunders) are gross errors, reported as such;
        # only when they are many they are the misfit itself
        flagged = np.any(np.abs(np.nan_to_num(w_i)) > 3.29, axis=1)
        if flagged.size and flagged.mean() <= 0.2:
            r_i, red = r_i[~flagged], red - 2 * int(flagged.sum())
    cost = float(np.sum(r_i**2) + np.sum(r_g**2))
    return float(np.sqrt(cost / red)) if red > 0 else float("nan")


def control_misfit(
    res: AdjustResult, observations: Observations, ground: GroundPoints | None
) -> dict[str, tuple[float, float, int]]:
    """Per image ``(adjusted px, given px, n)``: median distance between the measurements of the
    GCPs and check points and their given coordinates projected with the adjusted model and
    with the model as given (the start of the adjustment; the median, so that a few gross
    errors do not dominate). A model that does not belong to its image is far off with both."""
    if ground is None or not len(ground.ids):
        return {}
    truth = dict(zip(ground.ids, np.asarray(ground.lonlath, float), strict=True))
    groups = res.setup.problem.groups
    given = res.setup.image_models(groups, tuple(g.theta0 for g in groups))
    out = {}
    for name, model in res.models.items():
        pairs = zip(observations.point_ids, observations.images, strict=True)
        sel = [i for i, (p, img) in enumerate(pairs) if img == name and p in truth]
        if not sel:
            continue
        g = np.stack([truth[observations.point_ids[i]] for i in sel])
        xy = np.asarray(observations.xy, float)[sel]
        dist = [
            float(np.median(np.linalg.norm(np.asarray(project(m, g)) - xy, axis=1)))
            for m in (model, given[name])
        ]
        out[name] = (dist[0], dist[1], len(sel))
    return out


def poor_fit_message(
    res: AdjustResult,
    s0: float,
    reasons: list[str] | tuple[str, ...] = (),
    observations: Observations | None = None,
    ground: GroundPoints | None = None,
) -> str:
    """Why the observations do not fit the models: snooping's limits reached (``reasons``,
    :func:`~._snooping.snooping_verdict`) and/or s0 far above 1; the worst images (RMS and mean
    residual, and how far their control points are from the adjusted and given models) and
    points, and the likely cause read from the residual pattern."""
    keep = ~res.removed if res.removed is not None else np.ones(len(res.observation_ids), bool)
    imgs = np.asarray(res.observation_images)
    control = control_misfit(res, observations, ground) if observations is not None else {}
    rows = []
    for name in dict.fromkeys(res.observation_images):
        sel = keep & (imgs == name)
        if not sel.any():
            continue
        r = res.residuals_px[sel]
        rms = float(np.sqrt(np.nanmean(np.sum(r**2, axis=1))))
        mean = np.nanmean(r, axis=0)
        rows.append((control.get(name, (0.0,))[0], rms, name, mean))
    rows.sort(key=lambda row: row[:2], reverse=True)

    def image(row) -> str:
        _, rms, n, m = row
        text = f"{n!r} (RMS {rms:.1f} px, mean residual {m[0]:+.1f}, {m[1]:+.1f} px"
        if n in control:
            adj, giv, k = control[n]
            text += (f"; its {k} GCP/check measurements are {adj:.3g} px (median) from their "
                     f"ground coordinates projected with the adjusted model, {giv:.3g} px with "
                     "the given one")  # fmt: skip
        return text + ")"

    worst_img = ", ".join(image(row) for row in rows[:3])
    w = np.max(np.abs(np.nan_to_num(res.standardized)), axis=1)
    order = [i for i in np.argsort(-w) if keep[i]][:5]
    worst_pts = ", ".join(
        f"{res.observation_ids[i]}@{res.observation_images[i]} (w {w[i]:.1f})" for i in order
    )
    misfit = float(np.mean(w[keep] > 3.29)) if keep.any() else 0.0
    # the models fit the bulk of the control when its median distance is a few sigma: then the
    # observations beyond the limits are gross errors, too many to remove safely
    sigma = float(np.median(observations.sigma_px)) if observations is not None else 1.0
    bulk_fits = bool(control) and all(adj <= 3.0 * sigma for adj, _, _ in control.values())
    systematic = not (reasons and bulk_fits) and (
        bool(reasons)
        or misfit > 0.2
        or any(np.linalg.norm(m) > 0.5 * rms for _, rms, _, m in rows[:2])
    )
    if reasons and bulk_fits:
        cause = (
            "more gross errors than snooping may remove, or a priori sigmas too optimistic for "
            "the model: the adjusted models fit the bulk of the GCPs and check points (median "
            f"within {3 * sigma:.2g} px), but the observations named above do not; check their "
            "measurements, coordinates and sigmas (or remove them and run again)"
        )
    elif systematic:
        cause = (
            f"the residuals are systematic ({100 * misfit:.0f} % of the observations beyond "
            "3.29 sigma): a model that does not belong to its image (e.g. two RPC files "
            "swapped, or a model of another scene), or a bias the chosen bias model cannot "
            "absorb"
        )
    else:
        cause = (f"a few observations dominate ({100 * misfit:.0f} % beyond 3.29 sigma): gross "
                 "errors left, or a priori sigmas too optimistic")  # fmt: skip
    fit = f"s0 = {s0:.3g} (least squares; {res.s0:.3g} robust)"
    if reasons:
        share = f"{100 * MAX_REMOVED_FRACTION:.0f} %"
        head = (
            f"the observations do not fit the models: snooping would remove "
            f"{'; '.join(reasons)}, more than the share of gross errors it may remove (at most "
            f"max(1, {share}) of the GCPs, of each image's GCPs and of each image's "
            f"observations); they are kept and flagged ({fit})."
        )
    else:
        head = f"{fit} is far above 1 (> {S0_WARN:g}): the observations do not fit the models."
    return (
        f"{head} Worst images: {worst_img}. Worst observations: {worst_pts}. Likely cause: {cause}."
    )


def _final_y(problem, sol):
    z = tuple(t - g.theta0 for t, g in zip(sol.theta, problem.groups, strict=True))
    u = (sol.ground - problem.origin) * problem.metres_per_unit
    return z, u


def _result(setup, sol, status, solver, observations, ground, removed):
    """The :class:`AdjustResult` of a solve, ``status`` its ``(converged, message)``."""
    converged, message = status
    theta = tuple(np.asarray(t) for t in sol.theta)  # (as make_result's)
    s0 = float(sol.s0)
    problem = setup.problem
    var = s0**2 if np.isfinite(s0) else 1.0
    q = sol.q_params.to_sparse() if isinstance(sol.q_params, Band) else np.asarray(sol.q_params)
    order = setup.obs_order
    m = len(observations.point_ids)
    img_r = np.asarray(sol.residuals_image)
    weights = np.concatenate([np.asarray(ob.weight) for ob in problem.images] + [np.zeros(0)])
    w_img, w_gnd = standardized(sol)
    rem_i = np.zeros(img_r.shape[0], dtype=bool) if removed is None else np.asarray(removed[0])
    rem_g = np.zeros(w_gnd.shape[0], dtype=bool) if removed is None else np.asarray(removed[1])
    res_px = np.full((m, 2), np.nan)
    std = np.full((m, 2), np.nan)
    res_px[order] = img_r / weights[:, None]
    std[order] = w_img
    gone = np.zeros(m, dtype=bool)
    gone[order] = rem_i
    blunders = np.any(np.abs(np.nan_to_num(std)) > solver.blunder_k, axis=1) | gone
    gw = np.asarray(problem.ground.weight)
    role = dict(zip(setup.point_ids, setup.point_role, strict=True))
    is_gcp = np.array([role[p] == "gcp" for p in setup.ground_ids], dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        g_res = np.where(gw > 0, np.asarray(sol.residuals_ground) / gw, np.nan)[is_gcp]
    g_w = np.max(np.abs(np.nan_to_num(w_gnd)), axis=1) if w_gnd.size else np.zeros(0)
    g_flag = ((g_w > solver.blunder_k) | rem_g) & is_gcp  # not the DEM heights of ties
    gcp_flagged = tuple(p for p, f in zip(setup.ground_ids, g_flag, strict=True) if f)
    gcp_removed = tuple(p for p, f in zip(setup.ground_ids, rem_g & is_gcp, strict=True) if f)
    gcp_w = tuple(float(w) for w, f in zip(g_w, g_flag, strict=True) if f)
    flat = np.concatenate([t.reshape(-1) for t in theta] + [np.zeros(0)])
    qpp = np.asarray(sol.q_points)
    report, report_all, excluded = None, None, ()
    if ground is not None and "check" in setup.point_role:
        models = setup.image_models(problem.groups, theta)
        bad = {p for p, b in zip(observations.point_ids, blunders, strict=True) if b}
        excluded = tuple(p for p, r in zip(setup.point_ids, setup.point_role, strict=True)
                         if r == "check" and p in bad)  # fmt: skip
        every = dict(zip(setup.point_ids, np.asarray(sol.ground), strict=True))
        est = {p: g for p, g in every.items() if p not in bad or role[p] != "check"}
        report = accuracy(models, observations, ground, est, s0=s0, title="adjusted")
        # every check point, flagged or not: the statistics a poor fit must still show
        report_all = (
            accuracy(models, observations, ground, every, s0=s0, title="adjusted, all checks")
            if excluded
            else report
        )
    return AdjustResult(
        models=setup.image_models(problem.groups, theta),
        blocks=setup.blocks(problem.groups, theta),
        param_names=setup.param_names,
        params=flat,
        param_sigma=np.sqrt(np.maximum(q.diagonal(), 0.0) * var),
        param_cov=q * var,
        point_ids=setup.point_ids,
        point_role=setup.point_role,
        ground=np.asarray(sol.ground),
        ground_sigma_m=np.sqrt(np.maximum(np.diagonal(qpp, axis1=1, axis2=2), 0.0) * var),
        ground_cov_m2=qpp * var,
        observation_ids=tuple(observations.point_ids),
        observation_images=tuple(observations.images),
        residuals_px=res_px,
        standardized=std,
        blunders=blunders,
        gcp_ids=tuple(p for p, k in zip(setup.ground_ids, is_gcp, strict=True) if k),
        ground_residuals_m=g_res,
        s0=s0,
        redundancy=int(sol.redundancy),
        cost=float(sol.cost),
        converged=converged,
        message=message,
        result=sol.result,
        num_steps=int(sol.num_steps),
        report=report,
        setup=setup,
        solution=sol,
        removed=gone,
        gcp_flagged=gcp_flagged,
        gcp_removed=gcp_removed,
        gcp_w=gcp_w,
        checks_excluded=excluded,
        report_all=report_all,
    )
