"""Many independent solves of one structure as a queue over a fixed number of vmapped lanes.

A vmapped while loop runs as many steps as its slowest member: a chunk of 512 robust bias
adjustments that take 8 steps on average runs 13, the most any of them needs. Here each of
``lanes`` vmapped lanes takes the next problem of the queue once its own has terminated
(continuous batching), so the loop runs about ``mean steps * problems / lanes`` steps plus one
straggler's tail. The steps are those of :class:`~._lm.StructuredGaussNewton` (``init``,
``step``, ``terminate``), driven here instead of by ``optx.least_squares``: the same iterates,
results and step counts as one solve per problem, without optimistix' implicit derivative
(differentiate :func:`~._solve.solve` itself, vmapped, for that).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Int, PyTree

REFILL_FRACTION = 0.125
"""Idle lanes (finished, not yet given a new problem), as a fraction of all lanes, at which
they are refilled: a refill gathers the new problems' arrays and initial states; waiting for a
few finished lanes costs a few idle lane-steps instead of a gather at every step."""
_OPTIONS: dict = {}
_TAGS: frozenset = frozenset()


def _take(tree, index):
    return jax.tree.map(lambda x: x[index], tree)


def _where(mask, a, b):
    """Per-lane select between two pytrees batched over lanes (``mask`` (L,))."""

    def pick(x, y):
        return jnp.where(mask.reshape(mask.shape + (1,) * (x.ndim - 1)), x, y)

    return jax.tree.map(pick, a, b)


def _put(out, index, values, mask):
    """``out[index[l]] = values[l]`` for the lanes ``l`` where ``mask``."""
    n = jax.tree.leaves(out)[0].shape[0]
    at = jnp.where(mask, index, n)  # out of range: dropped
    return jax.tree.map(lambda o, v: o.at[at].set(v, mode="drop"), out, values)


def _finite(y) -> Array:
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(y)]))


def run_queue(
    make: Callable[[PyTree], tuple[Any, PyTree]],
    data: PyTree,
    *,
    lanes: int,
    max_steps: int,
) -> tuple[PyTree, Int[Array, " n"], Int[Array, " n"], PyTree]:
    """Solve every problem of ``data`` (arrays with a leading axis of ``n`` problems):
    ``make(one problem's arrays) -> (solver, start)`` gives its
    :class:`~._lm.StructuredGaussNewton` and starting unknowns. Returns, per problem, the
    unknowns where its iterations ended, the optimistix result code (``nonfinite`` for
    non-finite unknowns, ``nonlinear_max_steps_reached`` after ``max_steps`` steps), the steps
    taken and the final state's ``weights`` (:class:`~._lm.Weights` or ``None``)."""
    n = jax.tree.leaves(data)[0].shape[0]
    lanes = max(1, min(int(lanes), n))
    ok = optx.RESULTS.successful._value
    ran_out = optx.RESULTS.nonlinear_max_steps_reached._value

    def start(index):  # problems ``index`` (L,): their arrays, start and initial state
        d = _take(data, index)

        def one(d1):
            solver, y = make(d1)
            return y, solver.init(None, y, None, _OPTIONS, None, None, _TAGS)

        y, state = jax.vmap(one)(d)
        return d, y, state

    def lane_step(d1, y, state):
        solver, _ = make(d1)
        y, state, _ = solver.step(None, y, None, _OPTIONS, state, _TAGS)
        done, result = solver.terminate(None, y, None, _OPTIONS, state, _TAGS)
        code = jnp.where(_finite(y), result._value, optx.RESULTS.nonfinite._value)
        return y, state, done, code, solver.solution(y, state)

    first = jnp.arange(lanes)
    d0, y0, state0 = start(first)
    out_y = jax.tree.map(lambda x: jnp.zeros((n, *x.shape[1:]), x.dtype), y0)
    out_w = jax.tree.map(lambda x: jnp.zeros((n, *x.shape[1:]), x.dtype), state0.weights)
    out = (out_y, jnp.zeros(n, jnp.int32), jnp.zeros(n, jnp.int32), out_w)

    def refill(args):
        index, active, d, y, state, steps, counter = args
        free = ~active
        nxt = counter + jnp.cumsum(free) - 1
        take = free & (nxt < n)
        d_new, y_new, s_new = start(jnp.where(take, nxt, 0))
        return (
            jnp.where(take, nxt, index),
            active | take,
            _where(take, d_new, d),
            _where(take, y_new, y),
            _where(take, s_new, state),
            jnp.where(take, 0, steps),
            counter + jnp.sum(take),
        )

    def body(carry):
        index, active, d, y, state, steps, counter, out = carry
        y, state, done, code, answer = jax.vmap(lane_step)(d, y, state)
        steps = steps + 1
        stop = done | (code != ok) | (steps >= max_steps)
        code = jnp.where(~done & (code == ok) & (steps >= max_steps), ran_out, code)
        finished = active & stop
        out = _put(out, index, (answer, code, steps, state.weights), finished)
        active = active & ~finished
        args = (index, active, d, y, state, steps, counter)
        idle = jnp.sum(~active)
        want = (idle >= max(1, int(REFILL_FRACTION * lanes))) | ~jnp.any(active)
        args = jax.lax.cond(want & (counter < n), refill, lambda a: a, args)
        return (*args, out)

    def cond(carry):
        return jnp.any(carry[1]) | (carry[6] < n)

    carry = (first, jnp.ones(lanes, bool), d0, y0, state0, jnp.zeros(lanes, jnp.int32))
    *_, out = jax.lax.while_loop(cond, body, (*carry, jnp.array(lanes), out))
    return out
