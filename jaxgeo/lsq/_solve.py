"""Solve: the bundle adjustment as a pure function of arrays (residuals, solve, statistics).

:func:`solve` takes a :class:`~jaxgeo.lsq.Problem` and a
:class:`~jaxgeo.lsq.SolverConfig` and returns a :class:`Solution`; both are pytrees,
so ``solve`` can be jitted (``eqx.filter_jit``), vmapped over independent problems of one
structure (e.g. Monte-Carlo noise on ``xy``) and differentiated (implicit function theorem,
through optimistix). Failures are data: ``Solution.result`` is a
:class:`~jaxgeo.lsq.RESULTS` per problem, raised only with ``throw=True``.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from .._runtime.arrays import zeros_like
from .._runtime.kept import kept_solve
from ._band import Band
from ._config import DEFAULT_SOLVER, SolverConfig
from ._covariance import cofactors, undetermined_unknowns
from ._ground import beyond_offset, with_frames
from ._lm import Reweighting, StructuredGaussNewton, Weights
from ._loss import irls_weights
from ._problem import Problem
from ._residuals import jacobians, residuals, thetas
from ._results import RESULTS
from ._schur import (
    Jacobians,
    NormalBlocks,
    normal_blocks,
    split_params,
    u_diagonal,
)
from ._trust_region import sum_squares


class Solution(eqx.Module):
    """Result of :func:`solve` (arrays only; see :class:`jaxgeo.bundle.AdjustResult`).

    Fields:
        theta: per group ``(n_blocks, n_params)`` adjusted parameters.
        ground: ``(n_points, 3)`` adjusted ground points ``(lon_deg, lat_deg, h_m)``.
        residuals_image: ``(M, 2)`` image residuals divided by their a priori sigma,
            observation blocks concatenated (``project - measured``; not robust-weighted).
        residuals_ground: ``(c, 3)`` ground residuals divided by sigma (ENU adjusted - given).
        q_params: ``(N, N)`` cofactor matrix of all parameters (a priori sigma 1; multiply
            by ``s0**2`` for the a posteriori covariance), groups in order, raveled; a
            :class:`~jaxgeo.lsq.Band` when the reduced system is banded (strips): the
            cofactors within the band only (neighbouring sub-scenes), linear in their number.
        q_points: ``(n_points, 3, 3)`` cofactor matrices of the points, ENU metres.
        redundancy_image: ``(M, 2)`` redundancy numbers of the image observations.
        redundancy_ground: ``(c, 3)`` redundancy numbers of the ground observations.
        inflation_params, inflation_points: ``Q_ii H_ii`` per unknown (see
            :class:`~jaxgeo.lsq._covariance.Covariance`): huge or NaN where the unknown is not
            determined.
        cost: sum of squared weighted residuals at the solution.
        s0: a posteriori standard deviation of unit weight (NaN without redundancy).
        result: :class:`~jaxgeo.lsq.RESULTS`: ``successful``, ``nonfinite``
            (non-finite measurements, models or cost: takes precedence), ``undetermined``
            (some unknowns not determined), ``not_converged`` (maximum number of steps, or
            IRLS weights still changing), or optimistix' own; ``num_steps``: solver steps
            taken (the reweighting's included).
        weight_image, weight_ground: ``(M,)``, ``(c,)`` IRLS weights ``rho'(|r|^2)`` at the
            solution (1 for ``"l2"``; where the reweighting failed, its last ones);
            ``cost``, ``s0``, the covariance and redundancy numbers are those of the problem
            weighted with them.
        redundancy: rows minus unknowns, without the removed observations' rows.
        unknowns: the solver's unknowns at the solution (scaled parameters, points): a warm
            ``start`` for a re-solve.
    """

    theta: tuple[Float[Array, "b p"], ...]
    ground: Float[Array, "n 3"]
    residuals_image: Float[Array, "M 2"]
    residuals_ground: Float[Array, "c 3"]
    q_params: Float[Array, "N N"] | Band
    q_points: Float[Array, "n 3 3"]
    redundancy_image: Float[Array, "M 2"]
    redundancy_ground: Float[Array, "c 3"]
    inflation_params: Float[Array, " N"]
    inflation_points: Float[Array, "n 3"]
    cost: Float[Array, ""]
    s0: Float[Array, ""]
    result: RESULTS
    num_steps: Int[Array, ""]
    weight_image: Float[Array, " M"]
    weight_ground: Float[Array, " c"]
    redundancy: Int[Array, ""]
    unknowns: Any = None


def initial_unknowns(problem: Problem):
    """The solver's starting point ``y0 = (z, u) = 0``: the initial parameters and points."""
    z0 = tuple(zeros_like(g.theta0) for g in problem.groups)
    return z0, zeros_like(problem.origin)


def unit_scales(problem: Problem) -> tuple[Float[Array, "b p"], ...]:
    """Parameter scales of 1 (``theta = theta0 + z``)."""
    return tuple(jnp.ones_like(g.theta0) for g in problem.groups)


_traced_once = eqx.filter_jit(jacobians)
""":func:`~._residuals.jacobians` as one nested program: a solve linearises in its iterations,
at its solution and for its scales, and a nested ``jit`` is traced once for the same argument
types (jax caches its jaxpr; each use is still lowered apart, pruned to the outputs it uses):
the demo's robust solve traced and lowered in 1.6-1.7 s instead of 1.9-2.8 s (three paired
runs, a loaded 2-core CPU; XLA compiles the inlined program in the same time as before)."""


def linearised(problem: Problem, scales, y, loss: str = "l2", loss_scale: float = 3.0) -> Jacobians:
    """:func:`~._residuals.jacobians`, traced once per argument types (:data:`_traced_once`);
    the ground frames computed first where ``problem`` has none (as :func:`solve_setup` does):
    the iterations' problem and the solution's then have the same type."""
    if problem.ground.frame is None:
        problem = with_frames(problem)
    return _traced_once(problem, scales, y, loss, loss_scale)


def blocks_at(
    problem: Problem, scales, y, loss: str = "l2", loss_scale: float = 3.0
) -> tuple[Jacobians, NormalBlocks]:
    """The Jacobian and normal-equation blocks at ``y``."""
    jac = linearised(problem, scales, y, loss, loss_scale)
    return jac, normal_blocks(jac, problem.structure)


def parameter_scales(
    problem: Problem, loss: str = "l2", loss_scale: float = 3.0
) -> tuple[Float[Array, "b p"], ...]:
    """Column scaling ``1 / sqrt(diag J^T J)`` of the parameters at the initial values."""
    _, blocks = blocks_at(
        problem, unit_scales(problem), initial_unknowns(problem), loss, loss_scale
    )
    d = u_diagonal(blocks, problem.structure)
    sc = jnp.where(d > 0.0, 1.0 / jnp.sqrt(jnp.where(d > 0.0, d, 1.0)), 1.0)
    return jax.lax.stop_gradient(split_params(sc, problem.structure))


IRLS_INNER_TOL = 0.5
"""Tolerance (``StructuredGaussNewton.tol``) of the reweighting's weighted solves. They only
steer it: a step below 0.5 sigma moves a Cauchy weight (threshold 3 sigma) by 0.11 at most, and
the final robust phase reaches the M-estimate to ``SolverConfig.tol`` from wherever they stop.
Against 0.1 (``irls_tol`` 0.05 against 0.01): 6.6 steps instead of 8.0 on
``benchmarks/speed/batch.py`` (answers within 3e-7 px); on ``benchmarks/speed/adjust_scale.py``
7 instead of 8 (Cauchy), 9 instead of 11 (Huber), same s0 to 1e-12 and the same gross errors
removed."""
REMOVED_WEIGHT = 1e-8
"""Weight factor of an observation removed as a gross error: it keeps the arrays (and the
compiled solve) of the same shape while its influence (``1e-16`` of the normal equations) is
nil; its rows leave the redundancy. (:func:`jaxgeo.bundle.snoop` also moves its measurement to the
last solution's prediction, so that a point left with removed observations only stays put.)"""


def _weighted(problem: Problem, w_img, w_gnd) -> Problem:
    """``problem`` with its image weights times ``sqrt(w_img)`` (M,) (blocks concatenated) and
    its ground weights times ``sqrt(w_gnd)`` (c,)."""
    sizes = [ob.xy.shape[0] for ob in problem.images]
    parts, start = [], 0
    for ob, n in zip(problem.images, sizes, strict=True):
        parts.append(ob.weight * jnp.sqrt(w_img[start : start + n]))
        start += n
    out = eqx.tree_at(lambda p: tuple(ob.weight for ob in p.images), problem, tuple(parts))
    gw = problem.ground.weight * jnp.sqrt(w_gnd)[:, None]
    return eqx.tree_at(lambda p: p.ground.weight, out, gw)


def solve(
    problem: Problem,
    solver: SolverConfig = DEFAULT_SOLVER,
    *,
    removed_image: Bool[Array, " M"] | None = None,
    removed_ground: Bool[Array, " c"] | None = None,
    irls_limit: Int[Array, ""] | None = None,
    start: tuple[Any, Float[Array, " M"], Float[Array, " c"]] | None = None,
    throw: bool = False,
    verbose: bool = False,
) -> Solution:
    """Adjust ``problem``: a pure function, jittable with ``eqx.filter_jit`` and vmappable.

    ``solver.method``: ``"lm"`` Levenberg-Marquardt over the Schur-complement descent
    (default), ``"gn"`` Gauss-Newton over the same descent, ``"dense"`` optimistix' own
    Levenberg-Marquardt with a dense QR on Jacobi-scaled parameters (small problems and
    cross-checks only).

    A robust ``solver.loss`` (on the image observations and the GCP coordinates) is solved by
    iteratively reweighted least squares first: least squares, then up to
    ``solver.irls_iterations`` weighted least-squares solves, each with the weights
    ``rho'(|r|^2)`` of the previous solution held fixed and continuing from it, until no weight
    changes by more than ``solver.irls_tol`` (else ``RESULTS.not_converged``); each is an
    ordinary least-squares problem, on which the trust region works as designed. Then
    Levenberg-Marquardt on ``sum rho(|r|^2)`` itself (image and ground residuals) goes from
    there to the M-estimate, with Newton's model of ``rho`` (:func:`~._loss.newton_corrected`):
    two steps from a settled reweighting. All of it is one optimistix solve
    (:class:`~._lm.StructuredGaussNewton` with a :class:`~._lm.Reweighting`): one loop of
    ``solver.max_steps`` steps at most, in which each problem of a ``vmap`` goes through the
    phases at its own pace; ``Solution.num_steps`` counts them all. ``method="dense"``
    solves least squares, then the robust objective from there (no reweighting).

    ``removed_image`` (M,, blocks concatenated) / ``removed_ground`` (c,): observations taken
    out as gross errors (weight ``REMOVED_WEIGHT``, rows out of the redundancy); arrays, so that
    removing observations does not recompile. ``irls_limit``: reweighted solves at most, an
    array at most ``solver.irls_iterations`` (default that): the data snooping asks for fewer
    while it is still finding gross errors, without a second compilation. ``start``: ``(unknowns,
    image weights, ground weights)`` to start the reweighting from (a previous
    :class:`Solution`'s ``unknowns``, ``weight_image``, ``weight_ground``: a re-solve after a
    few observations were removed then takes a few steps); default the models' values and
    weights 1, least squares first.

    The outcome is ``Solution.result`` (see :class:`Solution`): singular normal equations are
    detected here, inside the compiled solve. ``throw=True`` raises (an ``equinox`` runtime
    error with the :class:`~jaxgeo.lsq.RESULTS` message) on any result other than
    ``successful``; under ``vmap`` each problem has its own result.
    """
    st = solve_setup(
        problem,
        solver,
        removed_image=removed_image,
        removed_ground=removed_ground,
        irls_limit=irls_limit,
        start=start,
        verbose=verbose,
    )
    out = solve_finish(problem, solver, st, *_iterate(st, solver, verbose))
    if throw:
        out = out.result.error_if(out, out.result != RESULTS.successful)
    return out


class Iterations(eqx.Module):
    """Where :func:`solve_iterations` ended: the unknowns ``y``, the result, the number of steps
    and the reweighting's last weights (``None`` without one)."""

    y: Any
    result: RESULTS
    steps: Int[Array, ""]
    weights: Weights | None


def solve_iterations(
    problem: Problem, solver: SolverConfig = DEFAULT_SOLVER, **kwargs
) -> Iterations:
    """The iterations of :func:`solve` (same arguments but ``throw``) without what follows them
    (:func:`solve_finished`): two programs whose compilations each need less memory than the
    whole solve's (a large problem, compiled apart)."""
    st = solve_setup(problem, solver, **kwargs)
    return Iterations(*_iterate(st, solver, kwargs.get("verbose", False)))


def solve_finished(
    problem: Problem, solver: SolverConfig, iterations: Iterations, **kwargs
) -> Solution:
    """:func:`solve`'s solution from its :func:`solve_iterations` (the same ``problem``,
    ``solver`` and keyword arguments): weights, covariance, redundancy numbers, s0, result."""
    st = solve_setup(problem, solver, **kwargs)
    it = iterations
    return solve_finish(problem, solver, st, it.y, it.result, it.steps, it.weights)


_kept = kept_solve(solve, parts=(solve_iterations, solve_finished))


def solve_kept(problem: Problem, solver: SolverConfig = DEFAULT_SOLVER, **kwargs) -> Solution:
    """:func:`solve` (the same arguments) of concrete arrays, called from the host: kept as a
    compiled program, traced at most once per problem structure across runs (a warm process
    traces nothing); a large problem as two programs, the iterations and what follows them,
    whose compilations each need less memory than the whole solve's. How it compiles is
    :func:`jaxgeo._runtime.kept.kept_solve`'s decision; the same solution as ``solve``, to the
    rounding of XLA's options. Within a transformation, ``solve`` jitted."""
    return _kept(problem, solver, **kwargs)


def _iterate(st: SolveSetup, solver: SolverConfig, verbose: bool):
    """``(y, result, steps, weights)`` where the iterations of ``st`` end."""
    if st.optimiser is None:
        y, result, steps = _dense(st.args, st.y, solver, verbose)
        return y, result, steps, None
    sol = optx.least_squares(
        residuals, st.optimiser, st.y, args=st.args, max_steps=solver.max_steps, throw=False
    )
    return sol.value, RESULTS.promote(sol.result), sol.stats["num_steps"], sol.state.weights


class SolveSetup(eqx.Module):
    """What :func:`solve` prepares before its iterations (:func:`solve_setup`) and needs after them
    (:func:`solve_finish`): the solver (``None`` for ``method="dense"``), the starting unknowns, the
    objective's ``args``, the removed observations and their weight factors."""

    optimiser: StructuredGaussNewton | None
    y: Any
    args: Any
    removed_image: Bool[Array, " M"]
    removed_ground: Bool[Array, " c"]
    base_image: Float[Array, " M"]
    base_ground: Float[Array, " c"]


def solve_setup(
    problem: Problem,
    solver: SolverConfig = DEFAULT_SOLVER,
    *,
    removed_image: Bool[Array, " M"] | None = None,
    removed_ground: Bool[Array, " c"] | None = None,
    irls_limit: Int[Array, ""] | None = None,
    start: tuple[Any, Float[Array, " M"], Float[Array, " c"]] | None = None,
    verbose: bool = False,
) -> SolveSetup:
    """The solver, start and objective of :func:`solve` (same arguments)."""
    s = problem.structure
    loss, c = solver.loss, float(solver.loss_scale)
    m, n_g = s.obs_point.shape[0], problem.ground.point.shape[0]
    rem_i = jnp.zeros(m, bool) if removed_image is None else jnp.asarray(removed_image)
    rem_g = jnp.zeros(n_g, bool) if removed_ground is None else jnp.asarray(removed_ground)
    base_i = jnp.where(rem_i, REMOVED_WEIGHT**2, 1.0)
    base_g = jnp.where(rem_g, REMOVED_WEIGHT**2, 1.0)
    limit = (
        solver.irls_iterations
        if irls_limit is None
        else jnp.minimum(irls_limit, solver.irls_iterations)
    )
    ones_i, ones_g = jnp.ones(m), jnp.ones(n_g)
    y_s, wi_s, wg_s = (initial_unknowns(problem), ones_i, ones_g) if start is None else start
    y_s, wi_s, wg_s = jax.lax.stop_gradient((y_s, wi_s, wg_s))
    if problem.ground.frame is None:  # once per solve, not at every evaluation
        problem = with_frames(problem)
    base = _weighted(problem, base_i, base_g)  # removed observations weighted out
    scales = _scales(problem, solver, c)
    # the objective: sum rho(|r|^2) of the image and ground residuals (optimistix'
    # implicit derivative is that of the M-estimate)
    args = (base, scales, loss, c)
    optimiser = None
    if solver.method != "dense":
        robust_ = None if loss == "l2" else (loss, c)
        reweighting = None
        if robust_ is not None:
            # the reweighting's weighted solves need not be exact: their weights are
            # refined by the next one and the final solve polishes the answer to ``tol``
            inner_tol = max(solver.tol, IRLS_INNER_TOL)
            reweighting = Reweighting(loss, c, solver.irls_tol, inner_tol, limit, wi_s, wg_s)
        optimiser = StructuredGaussNewton(
            s,
            residuals,
            (base, scales, "l2", c),
            tol=solver.tol,
            method=solver.method,
            verbose=verbose,
            robust=robust_,
            reweighting=reweighting,
            jacobians=_jacobians,
        )
    return SolveSetup(optimiser, y_s, args, rem_i, rem_g, base_i, base_g)


def _jacobians(y, args) -> Jacobians:
    problem, scales, loss, c = args
    return linearised(problem, scales, y, loss, c)


def solve_finish(
    problem: Problem,
    solver: SolverConfig,
    st: SolveSetup,
    y,
    result: RESULTS,
    steps: Int[Array, ""],
    weights: Weights | None,
) -> Solution:
    """The :class:`Solution` at the unknowns ``y`` where the iterations of ``st`` ended (with
    ``result`` after ``steps``; ``weights`` the reweighting's last, or ``None``): weights at the
    solution, covariance, redundancy numbers, s0, and the result (not converged, undetermined)."""
    s = problem.structure
    loss, c = solver.loss, float(solver.loss_scale)
    scales = st.args[1]
    rem_i, rem_g, base_i, base_g = (
        st.removed_image,
        st.removed_ground,
        st.base_image,
        st.base_ground,
    )
    if weights is None:
        # not weakly typed (as ``base_*`` are): a solve started from these weights (data
        # snooping's re-solve) has the types of a cold start, and reuses its compiled program
        w_i, w_g = jnp.ones(base_i.shape), jnp.ones(base_g.shape)
    else:
        w_i, w_g = weights.img, weights.gnd
    ok = result == RESULTS.successful
    plain_img, plain_gnd, _ = residuals(y, (problem, scales, "l2", c))
    if loss != "l2":
        # the weights at the M-estimate itself (the reweighting's last ones are up to
        # ``irls_tol`` off): the covariance and the reported weights are those of the solution;
        # where the reweighting failed, its last ones
        w_at = jax.lax.stop_gradient(
            (
                irls_weights(jnp.sum(plain_img_all(plain_img) ** 2, axis=-1), loss, c),
                irls_weights(jnp.sum(plain_gnd**2, axis=-1), loss, c),
            )
        )
        w_i, w_g = (jnp.where(ok, a, b) for a, b in zip(w_at, (w_i, w_g), strict=True))
    weighted = _weighted(problem, base_i * w_i, base_g * w_g)
    jac, blocks = blocks_at(weighted, scales, y, "l2", c)
    cov = cofactors(jac, blocks, s)
    flat_scale = jnp.concatenate([x.reshape(-1) for x in scales] + [jnp.zeros(0)])
    if isinstance(cov.cc, Band):
        q_params = cov.cc.scaled(flat_scale)
    else:
        q_params = cov.cc * flat_scale[:, None] * flat_scale[None, :]
    cost = sum_squares((jac.r, jac.rg, jac.rpr))
    gw = problem.ground.weight
    red = (
        problem.redundancy
        - 2 * jnp.sum(rem_i)
        - jnp.sum(jnp.where(rem_g[:, None] & (gw > 0), 1, 0))
    )
    s0 = jnp.where(red > 0, jnp.sqrt(cost / jnp.maximum(red, 1)), jnp.nan)
    bad_params, bad_points = undetermined_unknowns(
        problem, q_params, cov.inflation_params, cov.inflation_points
    )
    result = RESULTS.where(
        result == RESULTS.nonlinear_max_steps_reached, RESULTS.not_converged, result
    )
    undetermined = (jnp.any(bad_params) | jnp.any(bad_points)) & (result != RESULTS.nonfinite)
    result = RESULTS.where(undetermined, RESULTS.undetermined, result)
    far = beyond_offset(problem, y[1]) & (result != RESULTS.nonfinite)
    result = RESULTS.where(far, RESULTS.outside_domain, result)
    out = Solution(
        theta=thetas(problem, y[0], scales),
        ground=problem.ground_points(y[1]),
        residuals_image=plain_img_all(plain_img),
        residuals_ground=plain_gnd,
        q_params=q_params,
        q_points=cov.pp,
        redundancy_image=1.0 - cov.obs,
        redundancy_ground=1.0 - cov.ground,
        inflation_params=cov.inflation_params,
        inflation_points=cov.inflation_points,
        cost=cost,
        s0=s0,
        result=result,
        num_steps=steps,
        weight_image=w_i,
        weight_ground=w_g,
        redundancy=red,
        unknowns=y,
    )
    return out


def plain_img_all(img) -> Float[Array, "M 2"]:
    """Image residual blocks concatenated (``(0, 2)`` without image observations)."""
    return jnp.concatenate(img) if img else jnp.zeros((0, 2))


def _scales(problem: Problem, solver: SolverConfig, c: float):
    """Parameter scales: Jacobi scaling for the dense solve, 1 for the Schur solves."""
    if solver.method == "dense":
        return parameter_scales(problem, "l2", c)
    return unit_scales(problem)


def _dense(args, y, solver: SolverConfig, verbose: bool):
    """optimistix' own Levenberg-Marquardt with a dense QR (``method="dense"``): least squares,
    then (a robust loss) the robust objective from there, no reweighting."""
    lm = optx.LevenbergMarquardt(solver.tol, solver.tol, linear_solver=lx.QR(), verbose=verbose)

    def run(a, y):
        sol = optx.least_squares(residuals, lm, y, a, max_steps=solver.max_steps, throw=False)
        return sol.value, RESULTS.promote(sol.result), sol.stats["num_steps"]

    problem, scales, loss, c = args
    y, result, steps = run((problem, scales, "l2", c), y)
    if loss == "l2":
        return y, result, steps
    y2, result2, steps2 = run(args, y)
    ok = result == RESULTS.successful
    y = jax.tree.map(lambda a, b: jnp.where(ok, a, b), y2, y)
    return y, RESULTS.where(ok, result2, result), steps + jnp.where(ok, steps2, 0)


solve_jit = eqx.filter_jit(solve)
""":func:`solve` compiled (``eqx.filter_jit``): one compilation per problem structure and
solver configuration."""
