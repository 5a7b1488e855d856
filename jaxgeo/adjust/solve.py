"""``jaxgeo.adjust``: bundle block adjustment of any set of sensor models.

Input: sensor models keyed by image name, image observations with a priori sigmas (px), and
ground points (GCPs as weighted observations with a sigma per east/north/up axis; check points
adjusted as tie points, their coordinates only used in the report). Output: an
:class:`AdjustResult` with the adjusted models, s0, parameter covariances, residuals per
observation, ground points with sigmas, and the convergence status (a non-converged solve warns
with :class:`~.errors.NotConvergedWarning` and returns the last state).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping
from typing import Any

import equinox as eqx
import numpy as np

from ..io.tables import GroundPoints, Observations
from ..models import AbstractSensorModel, Biased
from ..models.bias import BIAS_KINDS, AbstractBias
from . import core
from .diagnose import undetermined
from .errors import NotConvergedWarning, SingularNormalEquations
from .report import AccuracyReport, accuracy, project
from .setup import Setup, build

BLUNDER_K = 3.29
"""Default threshold of the standardised residuals (Baarda's w-test at alpha = 0.001)."""

_solve_jit = eqx.filter_jit(core.solve)


def with_bias(models: Mapping[str, Any], bias: str | type[AbstractBias] | None) -> dict[str, Any]:
    """Wrap every single-image model in :class:`~jaxgeo.models.Biased` with a zero bias.

    ``bias``: ``"shift"``, ``"shift-drift"``, ``"affine"``, a bias class, or ``None``/``"none"``
    (models unchanged). Models that are already :class:`Biased` are kept as they are.
    """
    if bias is None or bias == "none":
        return dict(models)
    kind = BIAS_KINDS.get(bias) if isinstance(bias, str) else bias
    if kind is None:
        raise ValueError(f"unknown bias {bias!r}; expected none, {', '.join(BIAS_KINDS)}")
    return {
        k: m
        if isinstance(m, Biased) or not isinstance(m, AbstractSensorModel)
        else Biased(m, kind())
        for k, m in models.items()
    }


@dataclasses.dataclass(frozen=True)
class AdjustResult:
    """The adjusted block (numpy arrays; sigmas a posteriori, i.e. scaled by ``s0**2``).

    Models: ``models`` image name -> adjusted sensor model; ``blocks`` the user's keys ->
    adjusted models (multi-image models under their tuple key).
    Parameters: ``param_names`` (``image.leaf[index]``), ``params``, ``param_sigma``,
    ``param_cov``.
    Points: ``point_ids``, ``point_role`` (gcp / check / tie), ``ground`` ``(n, 3)``
    lon/lat/h, ``ground_sigma_m`` ``(n, 3)`` east/north/up, ``ground_cov_m2`` ``(n, 3, 3)``.
    Observations (in the order given: ``observation_ids``, ``observation_images``):
    ``residuals_px`` ``(m, 2)`` = project(adjusted) - measured, ``standardized`` ``(m, 2)``
    (residual / (sigma sqrt(redundancy number))),
    ``blunders`` ``(m,)`` where ``|standardized| > blunder_k``; ``ground_residuals_m``
    ``(c, 3)`` adjusted - given ENU for the GCPs ``gcp_ids``.
    Statistics: ``s0``, ``redundancy``, ``cost`` (sum of squared weighted residuals),
    ``converged``, ``message``, ``num_steps``; ``report`` (check points, tables 2-6 of 000_)
    or None.
    """

    models: dict[str, Any]
    blocks: dict[Any, Any]
    param_names: tuple[str, ...]
    params: np.ndarray
    param_sigma: np.ndarray
    param_cov: np.ndarray
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
    num_steps: int
    report: AccuracyReport | None
    setup: Setup = dataclasses.field(repr=False)
    solution: core.Solution = dataclasses.field(repr=False)

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


def _message(status) -> tuple[bool, str]:
    code = int(status)
    return code == 0, core.STATUS[code]


def _raise_singular(setup: Setup, params: list[int], points: list[int], when: str):
    pnames = [setup.param_names[i] for i in params]
    qnames = [setup.point_ids[j] for j in points]
    # undetermined parameters leave the points they carry undetermined too: name the cause
    what = [f"parameter(s) {', '.join(pnames[:12])}" + (" ..." if len(pnames) > 12 else "")]
    if qnames and not pnames:
        what = [f"ground point(s) {', '.join(map(repr, qnames[:10]))}"]
    raise SingularNormalEquations(
        f"singular normal equations{when}: not determined: {'; '.join(what)} "
        "(add GCPs or tie points, or choose fewer adjustable parameters)",
        parameters=pnames,
        points=qnames,
    )


def adjust(
    models: Mapping[Any, Any],
    observations: Observations,
    ground: GroundPoints | None = None,
    *,
    bias: str | type[AbstractBias] | None = None,
    filters: Any = None,
    prior_sigma: Any = None,
    initial: Mapping[str, Any] | None = None,
    method: str = "lm",
    loss: str = "l2",
    loss_scale: float = 3.0,
    blunder_k: float = BLUNDER_K,
    max_steps: int = 50,
    tol: float = 1e-6,
    check: bool = True,
) -> AdjustResult:
    """Bundle block adjustment.

    Args:
        models: image name -> sensor model; a multi-image model (``image(i)`` views sharing
            parameters, e.g. a ``KeplerSequence``) under a tuple of image names.
        observations: image measurements (``jaxgeo.io.read_observations``).
        ground: GCPs and check points (``jaxgeo.io.read_ground``); points measured in images
            but absent here are tie points.
        bias: wrap every single model in ``Biased(model, bias())`` first (``"shift"``,
            ``"shift-drift"``, ``"affine"``); the bias leaves are then adjusted.
        filters: ``eqx.partition`` filter spec of the adjustable leaves, one for all models or a
            mapping keyed like ``models``; default :func:`~.params.default_filter`.
        prior_sigma: optional parameter priors (``theta0 +- sigma``): scalar, raveled array or
            a pytree like the model, one for all or per model key (``inf`` = no prior).
        initial: optional initial ground points ``{id: (lon, lat, h)}`` (else intersection).
        method: ``"lm"`` (Levenberg-Marquardt, Schur), ``"gn"`` (Gauss-Newton, Schur) or
            ``"dense"`` (optimistix LM with dense QR; small problems only).
        loss: ``"l2"``, ``"huber"`` or ``"cauchy"`` on the image observations, threshold
            ``loss_scale`` a priori sigmas.
        blunder_k: flag observations with a standardised residual above this.
        max_steps, tol: solver limits (see :func:`jaxgeo.adjust.core.solve`).
        check: check the GCP count of every image against its adjustable parameters before
            solving (1 shift, 2 shift+drift, 3 affine, 4 non-coplanar for the 3D affine model).

    Raises :class:`~.errors.AdjustmentError` (bad input, too few GCPs) before solving, and
    :class:`~.errors.SingularNormalEquations` naming the undetermined parameters or points.
    """
    if bias is not None:
        models = with_bias(models, bias)
    setup = build(
        models,
        observations,
        ground,
        filters=filters,
        prior_sigma=prior_sigma,
        initial=initial,
        loss=loss,
        loss_scale=loss_scale,
        check_control=check,
    )
    sol = _solve_jit(setup.problem, method=method, max_steps=max_steps, tol=tol)
    return finish(setup, sol, observations, ground, blunder_k)


def finish(
    setup: Setup,
    sol: core.Solution,
    observations: Observations,
    ground: GroundPoints | None,
    blunder_k: float = BLUNDER_K,
) -> AdjustResult:
    """The :class:`AdjustResult` of a solved :class:`Setup` (``build`` + ``core.solve`` done
    elsewhere, e.g. inside a larger jitted function): raises
    :class:`~.errors.SingularNormalEquations` naming the undetermined unknowns, warns
    :class:`~.errors.NotConvergedWarning` if the solve did not converge."""
    problem = setup.problem
    converged, message = _message(sol.status)
    theta = tuple(np.asarray(t) for t in sol.theta)
    s0 = float(sol.s0)
    bad_params, bad_points = _undetermined(sol, problem)
    if bad_params or bad_points:
        if not np.all(np.isfinite(np.asarray(sol.inflation_params))):  # Cholesky failed: find
            bad_params, more = undetermined(problem, *_final_y(problem, sol))  # the null space
            bad_points = more if more else bad_points
        _raise_singular(setup, bad_params, bad_points, "")
    if not converged:
        warnings.warn(
            f"bundle adjustment did not converge ({message}) after {int(sol.num_steps)} steps; "
            f"returning the last state (cost {float(sol.cost):.6g}, s0 {s0:.4g})",
            NotConvergedWarning,
            stacklevel=3,
        )
    return _result(setup, sol, theta, s0, converged, message, blunder_k, observations, ground)


INFLATION_MAX = 1e6
"""An unknown whose variance is this many times that of an uncorrelated one (its sigma amplified
1000x by correlations) is numerically undetermined; minimal legitimate set-ups stay below ~1e3."""


def _undetermined(sol, problem) -> tuple[list[int], list[int]]:
    ip = np.asarray(sol.inflation_params)
    iq = np.asarray(sol.inflation_points)
    # a parameter with a prior is determined by it, however weakly the observations see it
    # (e.g. the common bias of a strip tied only to itself): only a variance above the prior's
    # (impossible in exact arithmetic) is then a numerical failure
    wt = np.concatenate(
        [
            np.asarray(w).reshape(-1) if np.shape(w)[1] else np.zeros(g.n_blocks * g.n_params)
            for w, g in zip(problem.prior_weight, problem.groups, strict=True)
        ]
        + [np.zeros(0)]
    )
    q = np.diag(np.asarray(sol.q_params))
    has_prior = wt > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        prior_ok = has_prior & (q * np.where(has_prior, wt, 0.0) ** 2 < 1.5)
    bad_p = np.flatnonzero(~(np.abs(ip) < INFLATION_MAX) & ~prior_ok)
    bad_q = np.flatnonzero(np.any(~(np.abs(iq) < INFLATION_MAX), axis=1))
    return [int(i) for i in bad_p], [int(j) for j in bad_q]


def _final_y(problem, sol):
    z = tuple(t - g.theta0 for t, g in zip(sol.theta, problem.groups, strict=True))
    u = (sol.ground - problem.origin) * problem.metres_per_unit
    return (z, u), None


def _result(setup, sol, theta, s0, converged, message, blunder_k, observations, ground):
    problem = setup.problem
    var = s0**2 if np.isfinite(s0) else 1.0
    q = np.asarray(sol.q_params)
    order = setup.obs_order
    m = len(observations.point_ids)
    img_r = np.asarray(sol.residuals_image)
    weights = np.concatenate([np.asarray(ob.weight) for ob in problem.images] + [np.zeros(0)])
    res_px = np.full((m, 2), np.nan)
    std = np.full((m, 2), np.nan)
    red = np.asarray(sol.redundancy_image)
    res_px[order] = img_r / weights[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        std[order] = np.where(red > 1e-10, img_r / np.sqrt(np.maximum(red, 1e-300)), np.nan)
    if problem.loss != "l2":  # report plain residuals, not the robust-scaled ones
        models = setup.image_models(problem.groups, theta)
        res_px = _plain_residuals(models, observations, sol, setup)
    blunders = np.any(np.abs(np.nan_to_num(std)) > blunder_k, axis=1)
    gw = np.asarray(problem.ground.weight)
    role = dict(zip(setup.point_ids, setup.point_role, strict=True))
    is_gcp = np.array([role[p] == "gcp" for p in setup.ground_ids], dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        g_res = np.where(gw > 0, np.asarray(sol.residuals_ground) / gw, np.nan)[is_gcp]
    flat = np.concatenate([t.reshape(-1) for t in theta] + [np.zeros(0)])
    qpp = np.asarray(sol.q_points)
    report = None
    if ground is not None and "check" in setup.point_role:
        models = setup.image_models(problem.groups, theta)
        est = {p: g for p, g in zip(setup.point_ids, np.asarray(sol.ground), strict=True)}
        report = accuracy(models, observations, ground, est, s0=s0, title="adjusted")
    return AdjustResult(
        models=setup.image_models(problem.groups, theta),
        blocks=setup.blocks(problem.groups, theta),
        param_names=setup.param_names,
        params=flat,
        param_sigma=np.sqrt(np.maximum(np.diag(q), 0.0) * var),
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
        redundancy=problem.redundancy,
        cost=float(sol.cost),
        converged=converged,
        message=message,
        num_steps=int(sol.num_steps),
        report=report,
        setup=setup,
        solution=sol,
    )


def _plain_residuals(models, observations, sol, setup) -> np.ndarray:
    ground = np.asarray(sol.ground)
    pidx = {p: j for j, p in enumerate(setup.point_ids)}
    out = np.zeros((len(observations.point_ids), 2))
    for name, model in models.items():
        sel = [i for i, img in enumerate(observations.images) if img == name]
        if not sel:
            continue
        g = ground[[pidx[observations.point_ids[i]] for i in sel]]
        out[sel] = np.asarray(project(model, g)) - observations.xy[sel]
    return out
