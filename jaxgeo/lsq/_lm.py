"""The structured Levenberg-Marquardt (or Gauss-Newton) solver: an optimistix least-squares
solver whose steps are Schur-complement solves (:mod:`._schur`).

One step evaluates the residuals and their Jacobian blocks once, at the candidate point
(``jacobians``, by default :func:`~._schur.split_jacobians`: ``width + 3`` JVPs; the solve
gives :func:`~._residuals.jacobians`, the same in chunks of observations; with a robust loss,
the plain residuals corrected by :func:`~._loss.newton_corrected`); the trust region judges
the candidate by the cost against the change the quadratic model at the last accepted point
predicted, computed from that point's normal blocks (:func:`~._schur.model_change`); an
accepted candidate's blocks are assembled and its undamped Gauss-Newton step solved; then the
next candidate is the damped step from the accepted point. The state carries the normal blocks,
not a linearisation of the residual function: under ``vmap`` every leaf of a while loop's state
is selected per problem at every step, and a small state is a small step program.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int, PyTree

from ._loss import corrected, irls_weights, newton_factors, rho
from ._problem import Structure
from ._schur import (
    Jacobians,
    NormalBlocks,
    model_change,
    normal_blocks,
    schur_solve,
    split_jacobians,
    split_params,
    zero_blocks,
)
from ._trust_region import NOISE_FLOOR, TrustRegion

CONVERGED_FLOOR = 1e-16
"""Relative cost reduction promised by the full step below which the solve has converged."""
STAGNANT_STEPS = 3
"""Accepted steps in a row that fail to halve a decrement already under the cost's rounding
noise (``NOISE_FLOOR`` of the cost) after which the solve has converged: the linear solve's own
rounding then sets the decrement (seen at 320 sub-scenes: 3e-12 for ever, above ``tol**2``)."""
CONTRACTION = 1e-2
"""Largest ratio of the decrement to the previous one for which the solve extrapolates: when
``decrement**2 / previous`` (the next decrement, were the contraction to go on as in the last
step; exact for linear convergence, an overestimate for quadratic) is below ``tol**2 / 100``,
the pending undamped Gauss-Newton step is taken as the last one without evaluating the point it
leads to (the solution's statistics are computed there anyway): the same answer one evaluation
earlier (8.4e-4 -> 1.1e-9 -> 1e-16 in the final phase of the demo's 9-GCP bias problems)."""
NEGLIGIBLE_DAMPING = 1e-6
"""Damping ``lambda`` (relative to ``diag(J^T J)``) at or below which a step is the undamped
Gauss-Newton step already solved at the accepted point: one factorisation per step instead of
two once the trust region has grown (``lambda = damping / step_size``, 1e-4 at the start, 10x
smaller after each very successful step). The trust region judges the step by the cost either
way."""


class Reweighting(eqx.Module):
    """The reweighting that brings a robust solve near its M-estimate first (iteratively
    reweighted least squares, as a globalisation): weighted least squares with the weights
    ``rho'(|r|^2)`` of the last point held fixed, to ``inner_tol``; then new weights from
    there, until no weight moves by more than ``tol`` after at least two weighted solves (the
    first with ``w_img, w_gnd``: ones for least squares); then Newton's model of ``rho``
    itself to the solver's ``tol``. Each reweighting continues from the point where the last
    weighted solve stopped, evaluated once (no restart). More than ``limit`` reweightings
    without settling end the solve with ``RESULTS.nonlinear_max_steps_reached``."""

    loss: str = eqx.field(static=True)
    c: float = eqx.field(static=True)
    tol: float = eqx.field(static=True)
    inner_tol: float = eqx.field(static=True)
    limit: Int[Array, ""] | int
    w_img: Float[Array, " M"]
    w_gnd: Float[Array, " c"]


class Weights(eqx.Module):
    """The reweighting's state: ``final`` (Newton's model of ``rho`` from here on), the weights
    of the weighted solve under way, the reweightings done, the last change of the weights."""

    final: Bool[Array, ""]
    img: Float[Array, " M"]
    gnd: Float[Array, " c"]
    rounds: Int[Array, ""]
    change: Float[Array, ""]


class LMState(eqx.Module):
    """State of :class:`StructuredGaussNewton` at the last accepted point ``y``.

    ``cost``: sum of squared (or ``rho``-) residuals at ``y``; ``blocks`` the normal blocks
    there (of the corrected residuals with a robust loss); ``dc, dp`` the undamped Gauss-Newton
    step and ``decrement`` its squared Newton decrement ``g^T H^-1 g`` (the squared length of
    the step in units of its own standard deviations; ``inf`` before the first step or when
    singular); ``stagnant`` accepted steps in a row whose decrement did not halve."""

    first_step: Bool[Array, ""]
    y_eval: PyTree
    cost: Float[Array, ""]
    blocks: NormalBlocks
    dc: Float[Array, " N"]
    dp: Float[Array, "n 3"]
    decrement: Float[Array, ""]
    previous: Float[Array, ""]
    """The decrement at the accepted point before (``inf`` after a change of the model)."""
    stagnant: Int[Array, ""]
    step_size: Float[Array, ""]
    since_acceptance: Int[Array, ""]
    result: optx.RESULTS
    weights: Weights | None


def _flat(z) -> Float[Array, " N"]:
    return jnp.concatenate([x.reshape(-1) for x in z] + [jnp.zeros(0)])


class StructuredGaussNewton(optx.AbstractLeastSquaresSolver):
    """Levenberg-Marquardt (``method="lm"``: Marquardt-scaled damping ``lambda diag(J^T J)``,
    clamped as in :mod:`._schur`, inside a :class:`~._trust_region.TrustRegion`) or Gauss-Newton
    (``"gn"``: undamped steps of length 1) over the Schur-complement solve.

    ``fn(y, args)`` gives the plain residuals ``(image blocks, ground, priors)``;
    ``jacobians(y, args)``, if given, their :class:`~._schur.Jacobians` (by default
    :func:`~._schur.split_jacobians` of ``fn``); ``robust``
    ``(loss, c)`` minimises ``sum rho(|r|^2)`` over the image and ground residuals instead of
    their squares, with Newton's model of ``rho`` (:func:`~._loss.newton_corrected`), after the
    ``reweighting`` (:class:`Reweighting`) when one is given. The function given to
    ``optx.least_squares`` is not evaluated by the steps: it defines the objective for
    optimistix' implicit derivative and must match (its residuals' squares sum to the robust
    cost).

    Termination is scale-free: the solve stops when the full Gauss-Newton step at the current
    point is shorter than ``tol`` of its own standard deviation (``g^T H^-1 g < tol^2``) or
    promises less than ``CONVERGED_FLOOR`` of the cost, or when it promises less than the cost's
    rounding noise and has stopped shrinking (``STAGNANT_STEPS``: large, ill-conditioned reduced
    systems, where the solve's rounding keeps it above ``tol**2``), or when ``max_rejections``
    steps in a row were rejected (the damping grew by 4^k without any decrease of the cost: the
    cost is at its floating-point floor). Parameters of very different units (pixels, pixels
    per pixel, metres) make a criterion on the raw parameters meaningless. A weighted solve of
    the reweighting ends by the same rules at ``inner_tol``.
    """

    structure: Structure
    fn: Callable = eqx.field(static=True)
    args: Any
    jacobians: Callable | None = eqx.field(static=True)
    robust: tuple[str, float] | None = eqx.field(static=True)
    reweighting: Reweighting | None
    tol: float = eqx.field(static=True)
    damped: bool = eqx.field(static=True)
    damping: float = eqx.field(static=True)
    max_rejections: int = eqx.field(static=True)
    verbose: bool = eqx.field(static=True)
    search: TrustRegion
    rtol: float
    atol: float
    norm: Callable[[PyTree], Array]

    def __init__(
        self,
        structure: Structure,
        fn: Callable,
        args: Any,
        tol: float = 1e-6,
        method: str = "lm",
        damping: float = 1e-4,
        max_rejections: int = 8,
        verbose: bool = False,
        robust: tuple[str, float] | None = None,
        reweighting: Reweighting | None = None,
        jacobians: Callable | None = None,
    ):
        if method not in ("lm", "gn"):
            raise ValueError(f"method must be 'lm' or 'gn', got {method!r}")
        if reweighting is not None and robust is None:
            raise ValueError("a reweighting needs a robust loss")
        self.structure = structure
        self.fn = fn
        self.args = args
        self.jacobians = jacobians
        self.robust = robust
        self.reweighting = reweighting
        self.tol = tol
        self.damped = method == "lm"
        self.damping = damping
        self.max_rejections = max_rejections
        self.verbose = verbose
        self.search = TrustRegion()
        self.rtol = self.atol = 0.0  # optimistix' criterion on the raw parameters: off
        self.norm = optx.max_norm

    def model(self, jac: Jacobians, weights: Weights | None) -> tuple[NormalBlocks, Array]:
        """Normal blocks and cost of the plain Jacobian blocks ``jac``: sums of squares
        (least squares), of ``rho`` (robust: Newton's model), or weighted least squares (a
        reweighting not yet ``final``)."""
        prior = sum((jnp.sum(r**2) for r in jac.rpr), jnp.zeros(()))
        sq = (jnp.sum(jac.r**2, axis=-1), jnp.sum(jac.rg**2, axis=-1))
        if self.robust is None:
            return normal_blocks(jac, self.structure), sum(jnp.sum(x) for x in sq) + prior
        loss, c = self.robust
        factors, cost = [], prior
        for k, sk in enumerate(sq):
            sqrt_rho1, root = newton_factors(sk, loss, c)
            terms = rho(sk, loss, c)
            if weights is not None:  # the reweighting's weighted least squares until final
                w = (weights.img, weights.gnd)[k]
                sqrt_rho1 = jnp.where(weights.final, sqrt_rho1, jnp.sqrt(w))
                root = jnp.where(weights.final, root, 1.0)
                terms = jnp.where(weights.final, terms, w * sk)
            factors.append((sqrt_rho1, root))
            cost = cost + jnp.sum(terms)
        r, jc, jp = corrected(jac.r, (jac.jc, jac.jp), *factors[0])
        rg, jg = corrected(jac.rg, (jac.jg,), *factors[1])
        jac = eqx.tree_at(lambda j: (j.r, j.jc, j.jp, j.rg, j.jg), jac, (r, jc, jp, rg, jg))
        return normal_blocks(jac, self.structure), cost

    def init(self, fn, y, args, options, f_struct, aux_struct, tags) -> LMState:
        del fn, args, options, f_struct, aux_struct, tags
        s = self.structure
        m = s.obs_point.shape[0]
        rw = self.reweighting
        weights = None
        if rw is not None:
            weights = Weights(
                final=jnp.array(False),
                img=jnp.asarray(rw.w_img, float),
                gnd=jnp.asarray(rw.w_gnd, float),
                rounds=jnp.array(0),
                change=jnp.array(jnp.inf),
            )
        return LMState(
            first_step=jnp.array(True),
            y_eval=y,
            cost=jnp.array(jnp.inf),
            blocks=zero_blocks(s, m),
            dc=jnp.zeros(s.n_params),
            dp=jnp.zeros((s.n_points, 3)),
            decrement=jnp.array(jnp.inf),
            previous=jnp.array(jnp.inf),
            stagnant=jnp.array(0),
            step_size=jnp.array(1.0),
            since_acceptance=jnp.array(0),
            result=optx.RESULTS.successful,
            weights=weights,
        )

    def _converged(self, state: LMState, tol: float) -> tuple[Array, Array]:
        """``(small, stalled)``: the decrement at the accepted point is below ``tol`` (or the
        floors), or ``max_rejections`` steps in a row were rejected."""
        cost = state.cost
        floor = jnp.maximum(tol**2, CONVERGED_FLOOR * cost)
        dec = state.decrement
        small = dec < floor
        small |= (dec < NOISE_FLOOR * cost) & (state.stagnant >= STAGNANT_STEPS)
        small |= self._extrapolated(state, tol)
        small &= ~state.first_step
        return small, state.since_acceptance >= self.max_rejections

    def _extrapolated(self, state: LMState, tol: float) -> Array:
        """Whether the pending step ends the solve by extrapolation (``CONTRACTION``): it is
        the undamped Gauss-Newton step, the last step contracted the decrement at least
        ``CONTRACTION`` times and the next decrement, so extrapolated, is below ``tol**2``."""
        dec, prev = state.decrement, state.previous
        undamped = True
        if self.damped:
            tiny = jnp.finfo(jnp.result_type(state.step_size)).tiny
            undamped = self.damping / jnp.maximum(state.step_size, tiny) <= NEGLIGIBLE_DAMPING
        # the extrapolated decrement 100x below tol**2: at tol**2 the answers of the 4000 9-GCP
        # bias problems of benchmarks/speed/batch.py were up to 3.6 tol from the M-estimate (taken
        # at tol 1e-10); with the margin they are those of the solve without extrapolation
        fast = (dec <= CONTRACTION * prev) & (dec * dec < 1e-2 * tol**2 * prev)
        fast &= jnp.isfinite(prev)
        return fast & undamped & ~state.first_step

    def solution(self, y, state: LMState):
        """The answer of a terminated solve: the accepted point ``y``, or the point its pending
        step leads to when the solve ended by extrapolation (:func:`_extrapolated`) and not by
        the decrement at ``y`` itself."""
        exact = state.decrement < jnp.maximum(self.tol**2, CONVERGED_FLOOR * state.cost)
        take = self._extrapolated(state, self.tol) & ~exact
        return jax.tree.map(lambda a, b: jnp.where(take, a, b), state.y_eval, y)

    def _reweigh(self, state: LMState, y):
        """Whether the weighted solve under way has ended, and the point to evaluate: its
        last, tiny, step ``state.y_eval`` when it converged (to ``inner_tol``), the accepted
        point ``y`` when it stalled."""
        small, stalled = self._converged(state, self.reweighting.inner_tol)
        reweigh = ~state.weights.final & (small | stalled)
        point = jax.tree.map(lambda a, b: jnp.where(reweigh & ~small, b, a), state.y_eval, y)
        return reweigh, point

    def _next_weights(self, w: Weights, reweigh, jac: Jacobians) -> tuple[Weights, Array]:
        """The weights ``rho'(|r|^2)`` of the plain residuals of ``jac`` for the next weighted
        solve, ``final`` once they settled (at least two weighted solves), and whether the
        reweighting failed (``limit`` reweightings without settling)."""
        rw = self.reweighting
        new_img = irls_weights(jnp.sum(jac.r**2, axis=-1), rw.loss, rw.c)
        new_gnd = irls_weights(jnp.sum(jac.rg**2, axis=-1), rw.loss, rw.c)
        change = jnp.maximum(
            jnp.max(jnp.abs(new_img - w.img), initial=0.0),
            jnp.max(jnp.abs(new_gnd - w.gnd), initial=0.0),
        )
        rounds = w.rounds + 1
        settled = (rounds >= 2) & (change <= rw.tol)
        failed = reweigh & ~settled & (rounds > rw.limit)
        new = Weights(
            final=w.final | (reweigh & settled),
            img=jnp.where(reweigh, new_img, w.img),
            gnd=jnp.where(reweigh, new_gnd, w.gnd),
            rounds=jnp.where(reweigh, rounds, w.rounds),
            change=jnp.where(reweigh, change, w.change),
        )
        return new, failed

    def step(self, fn, y, args, options, state: LMState, tags):
        del fn, args, options, tags
        s = self.structure
        weights, point = state.weights, state.y_eval
        reweigh = failed = jnp.array(False)
        if weights is not None:
            reweigh, point = self._reweigh(state, y)
        # one evaluation: the plain residuals and Jacobian blocks, then the weights (a
        # function of these residuals) and the model
        if self.jacobians is None:
            jac = split_jacobians(self.fn, self.args, point, s.width)
        else:
            jac = self.jacobians(point, self.args)
        if weights is not None:
            weights, failed = self._next_weights(weights, reweigh, jac)
        blocks_eval, cost_eval = self.model(jac, weights)
        if self.damped:
            z_diff, u_diff = jax.tree.map(lambda a, b: a - b, point, y)
            change = model_change(state.blocks, s, _flat(z_diff), u_diff)
            accept, step_size = self.search.update(
                state.first_step, 0.5 * state.cost, 0.5 * cost_eval, change, state.step_size
            )
            # a new weighted solve (or the final one) starts from the reweighting's point, with
            # the trust region as it was (restarting it at lambda = 1e-4 delays the undamped
            # steps that end a solve: 6.5 steps instead of 6.0 on benchmarks/speed/batch.py)
            accept = accept | reweigh
            step_size = jnp.where(reweigh, state.step_size, step_size)
        else:
            accept, step_size = jnp.array(True), jnp.array(1.0)

        def accepted():  # the undamped step and its decrement at the new point
            dc, dp = schur_solve(blocks_eval, s, 0.0)
            dec = jnp.dot(blocks_eval.gc[: s.n_params], dc) + jnp.sum(blocks_eval.gp * dp)
            dec = jnp.where(jnp.isfinite(dec), dec, jnp.inf)
            stagnant = jnp.where(dec > 0.5 * state.decrement, state.stagnant + 1, 0)
            previous = jnp.where(reweigh, jnp.inf, state.decrement)  # a new model: no history
            return blocks_eval, cost_eval, dc, dp, dec, previous, jnp.where(reweigh, 0, stagnant)

        def rejected():
            return (
                state.blocks,
                state.cost,
                state.dc,
                state.dp,
                state.decrement,
                state.previous,
                state.stagnant,
            )

        blocks, cost, dc, dp, dec, previous, stagnant = jax.lax.cond(accept, accepted, rejected)
        y = jax.tree.map(lambda a, b: jnp.where(accept, a, b), point, y)
        if self.verbose:
            jax.debug.print(
                "cost: {c} candidate: {ce} accepted: {a} step size: {t} decrement: {d}",
                c=state.cost,
                ce=cost_eval,
                a=accept,
                t=step_size,
                d=dec,
            )
        dc_step, dp_step, result = self._step(step_size, blocks, dc, dp)
        result = optx.RESULTS.where(failed, optx.RESULTS.nonlinear_max_steps_reached, result)
        # a non-finite cost where a point is accepted regardless (the start, a reweighting):
        # non-finite measurements or models; nothing after it could be trusted
        bad = accept & ~jnp.isfinite(cost_eval)
        result = optx.RESULTS.where(bad, optx.RESULTS.nonfinite, result)
        y_eval = (
            tuple(a - b for a, b in zip(y[0], split_params(dc_step, s), strict=True)),
            y[1] - dp_step,
        )
        new = LMState(
            first_step=jnp.array(False),
            y_eval=y_eval,
            cost=cost,
            blocks=blocks,
            dc=dc,
            dp=dp,
            decrement=dec,
            previous=previous,
            stagnant=stagnant,
            step_size=step_size,
            since_acceptance=jnp.where(accept, 0, state.since_acceptance + 1),
            result=result,
            weights=weights,
        )
        return y, new, None

    def _step(self, step_size, blocks: NormalBlocks, dc, dp):
        """The damped step ``(dc, dp)`` for the trust region's ``step_size`` (``lambda =
        damping / step_size``; the undamped one once ``lambda <= NEGLIGIBLE_DAMPING``), or the
        Gauss-Newton step itself when not damped."""
        if not self.damped:
            finite = jnp.all(jnp.isfinite(dc)) & jnp.all(jnp.isfinite(dp))
            result = optx.RESULTS.where(finite, optx.RESULTS.successful, optx.RESULTS.nonfinite)
            return dc, dp, result
        tiny = jnp.finfo(jnp.result_type(step_size)).tiny
        lam = self.damping / jnp.maximum(step_size, tiny)
        # a non-finite damped step is rejected by the trust region, which then damps more
        dc, dp = jax.lax.cond(
            lam <= NEGLIGIBLE_DAMPING,
            lambda: (dc, dp),
            lambda: schur_solve(blocks, self.structure, lam),
        )
        return dc, dp, optx.RESULTS.successful

    def terminate(self, fn, y, args, options, state: LMState, tags):
        del fn, y, args, options, tags
        small, stalled = self._converged(state, self.tol)
        done = small | stalled
        if state.weights is not None:
            done &= state.weights.final
        return done | (state.result != optx.RESULTS.successful), state.result

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        del fn, args, options, tags, result
        return self.solution(y, state), aux, {}
