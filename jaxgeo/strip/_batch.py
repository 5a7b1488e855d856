"""One strip's compiled two-level call run many times: timing and Monte-Carlo batches.

:func:`monte_carlo` draws fresh measurement noise for the GCP and check measurements and
adjusts every draw in one jitted call (:func:`~._solve.two_level_batch`). A batch is
the compiled call alone: the solver's robust loss acts, but nothing is removed (data snooping
is a host-side loop around one strip, :func:`~._adjustment.adjust_strip`); the level-2 GCP
weights are the result's (GCP measurements removed there stay out). With several local devices
(on a CPU jaxgeo makes one per usable core: :mod:`jaxgeo._runtime.jaxconfig`) the draws are
shared out over them (:func:`two_level_sharded`), each device adjusting its draws one after
another on its own core.
"""

from __future__ import annotations

import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._runtime.shard import shard_map
from ._result import StripResult
from ._solve import Evaluation, TwoLevelSolution, degree_index, two_level_batch, two_level_jit


def time_two_level(result: StripResult, repeat: int = 3) -> float:
    """Best wall time (s) of the compiled two-level call on ``result``'s problem."""
    c = result.config
    args = (result.setup.problem, result.data, degree_index(c.level2.degree), c.solver)
    jax.block_until_ready(two_level_jit(*args))
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(two_level_jit(*args))
        best = min(best, time.perf_counter() - t)
    return best


def monte_carlo_inputs(
    result: StripResult, n_runs: int, noise_px: float | None = None, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noisy measurement sets for :func:`~._solve.two_level_batch`: ``(xy (b, m, 2),
    gcp_xy (b, g, 2), check_xy (b, c, 2))``. Fresh Gaussian noise (``noise_px``, default each
    measurement's a priori sigma) on the GCP and check measurements, the same draw wherever a
    measurement enters (level 1 and level 2); formed and measured ties stay as they are."""
    rng = np.random.default_rng(seed)
    data, inp = result.data, result.inputs
    o = result.strip.observations
    rows = result.report.rows
    sigma = o.sigma_px if noise_px is None else np.full(len(o.sigma_px), float(noise_px))
    n_ties, n_gcp = len(inp.ties.point), len(rows["gcp"])
    xy, gcp_xy, check_xy = [], [], []
    for _ in range(n_runs):
        e = rng.normal(0.0, 1.0, o.xy.shape) * sigma[:, None]
        e_gcp, e_chk = e[rows["gcp"]], e[rows["check"]]
        noisy = np.array(inp.observations.xy)
        if result.config.level1.use_gcps:
            noisy[n_ties : n_ties + n_gcp] += e_gcp  # level-1 GCP rows, in rows["gcp"] order
        xy.append(noisy[result.setup.obs_order])
        gcp_xy.append(np.asarray(data.gcp_xy) + e_gcp)
        check_xy.append(np.asarray(data.check_xy) + e_chk)
    return np.stack(xy), np.stack(gcp_xy), np.stack(check_xy)


def monte_carlo(
    result: StripResult, n_runs: int, noise_px: float | None = None, seed: int = 0
) -> tuple[TwoLevelSolution, Evaluation]:
    """``n_runs`` Monte-Carlo repetitions of ``result``'s two-level adjustment (noise as in
    :func:`monte_carlo_inputs`) in one jitted call. Returns the batched solution and
    evaluation (leading axis ``n_runs``)."""
    xy, gcp_xy, check_xy = monte_carlo_inputs(result, n_runs, noise_px, seed)
    c = result.config
    return two_level_sharded(
        result.setup.problem, result.data, xy, gcp_xy, check_xy, degree_index(c.level2.degree),
        c.solver,
    )  # fmt: skip


def two_level_sharded(problem, data, xy, gcp_xy, check_xy, degree, solver, *, shard=True):
    """:func:`~._solve.two_level_batch` with the batch shared out over the local devices
    (``shard_map`` over the first axis, padded with copies of the last item to a multiple of
    their number; each device runs its items one after another): the same results as one
    device. One device, one item, or ``shard=False``: :func:`~._solve.two_level_batch`."""
    xy, gcp_xy, check_xy = (jnp.asarray(a, dtype=float) for a in (xy, gcp_xy, check_xy))
    n = xy.shape[0]
    devices = min(jax.local_device_count(), n) if shard else 1
    if devices < 2:
        return two_level_batch(problem, data, xy, gcp_xy, check_xy, degree, solver)
    total = -(-n // devices) * devices
    batch = tuple(
        jnp.concatenate([a, jnp.repeat(a[-1:], total - n, 0)]) for a in (xy, gcp_xy, check_xy)
    )
    mesh = jax.sharding.Mesh(np.array(jax.local_devices()[:devices]), ("runs",))
    out = _sharded(problem, data, batch, degree, solver, mesh)
    return jax.tree.map(lambda a: a[:n], out)


@eqx.filter_jit
def _sharded(problem, data, batch, degree, solver, mesh):
    fixed, static = eqx.partition((problem, data, degree), eqx.is_array)
    spec, whole = jax.sharding.PartitionSpec("runs"), jax.sharding.PartitionSpec()

    def run(fixed, xy, gcp_xy, check_xy):  # one device's items
        p, d, g = eqx.combine(fixed, static)
        return two_level_batch(p, d, xy, gcp_xy, check_xy, g, solver)

    return shard_map(run, mesh, in_specs=(whole, spec, spec, spec), out_specs=spec)(fixed, *batch)
