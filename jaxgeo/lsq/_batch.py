"""Many independent adjustments of one structure in one compiled call.

Each problem has its own models, measurements, control and priors, but the same sparsity (the
same images, points and observation pattern: e.g. 10 000 scenes each bias-adjusted with its 9
GCPs, or Monte-Carlo draws of one block). :func:`solve_batch` stacks them leaf-wise and
solves them as a queue over ``chunk`` vmapped lanes (:mod:`~jaxgeo.lsq._lanes`): a lane
takes the next problem once its own has converged, so that a straggler holds up one lane, not
a chunk; the statistics of the solutions (covariance, redundancy numbers) follow in vmapped
chunks of ``chunk`` problems. The iterates, results and step counts are those of
:func:`~jaxgeo.lsq.solve` on each problem (not its implicit derivative: vmap ``solve``
to differentiate). The small factorisations are LAPACK-free
(:mod:`~jaxgeo.lsq._factor`), which removes the hang of >= 1000 vmapped problems in jaxlib's
batched LAPACK; problems whose reduced system is larger (LAPACK) run one at a time. With
several local devices (``jax.local_device_count() > 1``; on a CPU jaxgeo makes one device per
usable core, :mod:`jaxgeo._runtime.jaxconfig`) the problems are sharded over them
(``shard_map``, one mesh axis), each device running its own queue of lanes on its own core:
the results are those of one device.

Example::

    setups = [build(models_i, obs_i, gcps_i) for ...]
    sol = solve_batch([s.problem for s in setups])
    sol.theta[0][k], sol.result[k], sol.s0[k]   # problem k
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._runtime.shard import shard_map
from ._config import DEFAULT_SOLVER, SolverConfig
from ._factor import UNROLL_MAX
from ._ground import with_frames
from ._lanes import run_queue
from ._problem import Problem
from ._results import RESULTS
from ._solve import Solution, solve, solve_finish, solve_setup

DEFAULT_CHUNK = 1024
"""Most problems per vmapped chunk (lanes) of :func:`solve_batch`: 10 000 Cauchy bias
adjustments take 0.44 s in lanes of 1024 (1000 once balanced: :func:`balanced_chunk`) against
0.46 / 0.48 / 0.47 / 0.48 s with 768 / 512 / 1536 / 2048 (2-core CPU, same runs): fewer loop
iterations for the same operations, until the last problems' tail costs more."""
LANE_ELEMENTS = 1 << 22
"""Lanes are also capped so that lanes x one problem's array elements stay below this (4 M
float64, 32 MiB of inputs; the solver's state is a small multiple of it): large problems run
fewer at a time."""


def stack_problems(problems: Sequence[Problem]) -> Problem:
    """Stack problems of one structure leaf-wise (leading axis = problem).

    The :class:`~jaxgeo.lsq._problem.Structure` (index arrays) is shared, not stacked.
    Raises ``ValueError`` naming the first problem whose structure or shapes differ from
    problem 0's."""
    problems = list(problems)
    if not problems:
        raise ValueError("solve_batch: no problems given")
    first = problems[0]
    ref_struct = jax.tree.map(np.asarray, first.structure)
    dyn0, static0 = eqx.partition(_without_structure(first), eqx.is_array)
    shapes0 = [x.shape for x in jax.tree.leaves(dyn0)]
    dyns = []
    for k, p in enumerate(problems):
        same = jax.tree.structure(p.structure) == jax.tree.structure(first.structure) and all(
            np.array_equal(a, np.asarray(b))
            for a, b in zip(jax.tree.leaves(ref_struct), jax.tree.leaves(p.structure), strict=True)
        )
        dyn, static = eqx.partition(_without_structure(p), eqx.is_array)
        if not same or jax.tree.structure(static) != jax.tree.structure(static0):
            raise ValueError(
                f"solve_batch: problem {k} has another structure than problem 0 (images, "
                "points or observation pattern differ); batch only problems of one structure"
            )
        shapes = [x.shape for x in jax.tree.leaves(dyn)]
        if shapes != shapes0:
            raise ValueError(f"solve_batch: problem {k}'s array shapes differ from problem 0's")
        dyns.append(dyn)
    stacked = jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *dyns)
    return _with_structure(eqx.combine(stacked, static0), first.structure)


def with_xy_batch(problem: Problem, xy) -> Problem:
    """``B`` copies of ``problem`` stacked for :func:`solve_batch`, copy ``b`` with the image
    measurements ``xy[b]`` (``(B, M, 2)``, all observation blocks concatenated in order, as
    :meth:`~jaxgeo.lsq.Problem.with_xy`): Monte-Carlo runs, or many scenes of one
    layout. Far faster than stacking ``B`` separate problems."""
    xy = jnp.asarray(xy, dtype=float)
    m = sum(ob.xy.shape[0] for ob in problem.images)
    if xy.ndim != 3 or xy.shape[1:] != (m, 2):
        raise ValueError(f"with_xy_batch: xy must have shape (B, {m}, 2), got {xy.shape}")
    dyn, static = eqx.partition(_without_structure(problem), eqx.is_array)
    dyn = jax.tree.map(lambda x: jnp.broadcast_to(x, (xy.shape[0], *jnp.shape(x))), dyn)
    stacked = eqx.combine(dyn, static)
    sizes = np.cumsum([0] + [ob.xy.shape[0] for ob in problem.images])
    parts = tuple(xy[:, a:b] for a, b in zip(sizes[:-1], sizes[1:], strict=True))
    stacked = eqx.tree_at(lambda p: tuple(ob.xy for ob in p.images), stacked, parts)
    return _with_structure(stacked, problem.structure)


def _without_structure(p: Problem) -> Problem:
    return eqx.tree_at(lambda q: q.structure, p, None, is_leaf=lambda x: x is None)


def _with_structure(p: Problem, structure) -> Problem:
    return eqx.tree_at(lambda q: q.structure, p, structure, is_leaf=lambda x: x is None)


@eqx.filter_jit
def _solve_stacked(stacked: Problem, solver: SolverConfig, chunk: int, mesh) -> Solution:
    structure = stacked.structure
    dyn, static = eqx.partition(_without_structure(stacked), eqx.is_array)
    if solver.method != "dense":
        # the ground residuals' frames once per problem, not at every step of a lane
        def framed(d):
            p = with_frames(_with_structure(eqx.combine(d, static), structure))
            return _without_structure(p)

        dyn, static = eqx.partition(eqx.filter_vmap(framed)(dyn), eqx.is_array)

    def problem(d):
        return _with_structure(eqx.combine(d, static), structure)

    def one(d):
        return solve(problem(d), solver)

    def make(d):
        st = solve_setup(problem(d), solver)
        return st.optimiser, st.y

    def run(d):  # the problems of one device (all of them without a mesh)
        if solver.method == "dense":
            return jax.lax.map(one, d, batch_size=chunk)
        # a queue over ``chunk`` vmapped lanes: a problem that converges early frees its lane
        y, code, steps, weights = run_queue(make, d, lanes=chunk, max_steps=solver.max_steps)
        result = RESULTS.promote(jax.tree.map(lambda _: code, optx.RESULTS.successful))

        def fin(args):
            d1, y1, r1, s1, w1 = args
            p = problem(d1)
            return solve_finish(p, solver, solve_setup(p, solver), y1, r1, s1, w1)

        return jax.lax.map(fin, (d, y, result, steps, weights), batch_size=chunk)

    if mesh is None:
        return run(dyn)
    spec = jax.sharding.PartitionSpec("problems")
    return shard_map(run, mesh, in_specs=spec, out_specs=spec)(dyn)


def _mesh(devices: int):
    """A one-axis mesh (problem axis) over the first ``devices`` local devices, or ``None``
    for one."""
    if devices < 2:
        return None
    return jax.sharding.Mesh(np.array(jax.local_devices()[:devices]), ("problems",))


def shard_count(n: int, shard: bool = True) -> int:
    """Devices a batch of ``n`` problems is spread over: all local devices (jaxgeo asks jax
    for one CPU device per usable core: :mod:`jaxgeo._runtime.jaxconfig`), at most ``n``; 1 without
    ``shard``."""
    return max(1, min(jax.local_device_count(), n)) if shard else 1


def default_chunk(stacked: Problem) -> int:
    """:data:`DEFAULT_CHUNK` lanes, fewer for problems of over ``LANE_ELEMENTS / DEFAULT_CHUNK``
    array elements each (:data:`LANE_ELEMENTS`)."""
    leaves = jax.tree.leaves(eqx.filter(_without_structure(stacked), eqx.is_array))
    per_problem = sum(x.size // x.shape[0] for x in leaves)
    return max(1, min(DEFAULT_CHUNK, LANE_ELEMENTS // max(per_problem, 1)))


def balanced_chunk(n: int, devices: int, chunk: int) -> int:
    """Problems per chunk for ``n`` problems over ``devices``: at most ``chunk``, as many
    chunks as that needs, of balanced sizes (the least padding: 10 000 problems in chunks of
    at most 1024 are 10 of 1000, not 10 of 1024 with 240 padded)."""
    chunk = max(1, min(int(chunk), n // devices))
    per_device = max(1, -(-n // devices))
    return -(-per_device // -(-per_device // chunk))


def solve_batch(
    problems: Sequence[Problem] | Problem,
    solver: SolverConfig = DEFAULT_SOLVER,
    *,
    chunk: int | None = None,
    shard: bool = True,
) -> Solution:
    """Adjust many independent problems of one structure in one compiled call.

    ``problems``: a sequence of :class:`~jaxgeo.lsq.Problem` (e.g.
    ``build(...).problem`` per scene) or one already stacked by :func:`stack_problems`.
    Returns one :class:`~jaxgeo.lsq.Solution` whose every array has a leading axis
    of problems; ``result`` and ``num_steps`` are per problem (a failed problem does not stop
    the others). Up to ``chunk`` problems are vmapped together (see the module docstring;
    default :func:`default_chunk`; chunks of balanced sizes); ``shard=True`` spreads the
    problems over all local devices when there are several (:func:`shard_count`; on a CPU,
    one device per core by default, so the cores share the batch), padding the batch to a
    whole number of chunks per device. The results are those of one device.
    """
    stacked = problems if isinstance(problems, Problem) else stack_problems(problems)
    n = jax.tree.leaves(eqx.filter(_without_structure(stacked), eqx.is_array))[0].shape[0]
    devices = shard_count(n, shard)
    mesh = _mesh(devices)
    chunk = balanced_chunk(n, devices, default_chunk(stacked) if chunk is None else chunk)
    if stacked.structure.n_params + 1 > UNROLL_MAX:
        # the reduced system goes to LAPACK, whose batched (vmapped) kernels deadlock on this
        # 2-core CPU (both XLA threads waiting in ParallelBatchMap): one problem at a time
        chunk = 1
    # pad (repeating the last problem) to whole chunks per device: lax.map then compiles one
    # body, and every batch size of a multiple of chunk * devices reuses one program
    total = -(-n // (chunk * devices)) * chunk * devices
    if total != n:
        dyn, static = eqx.partition(_without_structure(stacked), eqx.is_array)
        dyn = jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], total - n, 0)]), dyn)
        stacked = _with_structure(eqx.combine(dyn, static), stacked.structure)
    sol = _solve_stacked(stacked, solver, chunk, mesh)
    if total == n:
        return sol
    arrays, rest = eqx.partition(sol, eqx.is_array)
    return eqx.combine(jax.tree.map(lambda x: x[:n], arrays), rest)


def solve_batch_distributed(
    problems: Sequence[Problem] | Problem,
    solver: SolverConfig = DEFAULT_SOLVER,
    *,
    chunk: int | None = None,
) -> Solution:
    """:func:`solve_batch` over several hosts (processes) started with
    ``jax.distributed.initialize``: every process passes the same problems, solves its share
    (contiguous, ``process_index`` of ``process_count``; on its local devices) and receives
    everyone's results (``multihost_utils.process_allgather``): the same :class:`Solution` as
    one process would compute. The number of problems must be divisible by the number of
    processes. With one process it is :func:`solve_batch`.
    """
    from jax.experimental import multihost_utils

    stacked = problems if isinstance(problems, Problem) else stack_problems(problems)
    count, index = jax.process_count(), jax.process_index()
    if count == 1:
        return solve_batch(stacked, solver, chunk=chunk)
    dyn, static = eqx.partition(_without_structure(stacked), eqx.is_array)
    n = jax.tree.leaves(dyn)[0].shape[0]
    if n % count:
        raise ValueError(f"solve_batch_distributed: {n} problems for {count} processes")
    per = n // count
    mine = jax.tree.map(lambda x: x[index * per : (index + 1) * per], dyn)
    own = _with_structure(eqx.combine(mine, static), stacked.structure)
    sol = solve_batch(own, solver, chunk=chunk, shard=False)
    arrays, rest = eqx.partition(sol, eqx.is_array)
    gathered = multihost_utils.process_allgather(arrays, tiled=True)
    return eqx.combine(jax.tree.map(jnp.asarray, gathered), rest)
