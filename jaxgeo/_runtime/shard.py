"""``jax.shard_map`` for jaxgeo's batches: the inputs' zero-size arrays stay out of the mapped call.

jaxlib 0.11.2 (the jaxlib of Python >= 3.12) kills the process (a segmentation fault in Shardy's
``ManualComputationUnusedInputsPattern``, while XLA compiles) when a ``shard_map`` takes a
zero-size array that its body uses: ``jnp.ones((4, 0))`` summed inside is enough, replicated or
sharded; jaxlib 0.10.2 compiles it. A problem whose model group has no prior rows has such
arrays (its prior means and weights, ``(images, 0)``): the strip's Monte-Carlo batch over several
CPU devices crashed there. A zero-size array
holds no values: :func:`shard_map` passes the others and makes the empty ones again inside, of
the same per-device shape and dtype.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

PartitionSpec = jax.sharding.PartitionSpec


def _local_shape(shape: tuple[int, ...], spec: PartitionSpec, mesh) -> tuple[int, ...]:
    """One device's block of an array of ``shape`` laid out by ``spec`` over ``mesh``."""
    local = list(shape)
    for i, axes in enumerate(spec):
        if axes is None:
            continue
        names = axes if isinstance(axes, tuple) else (axes,)
        local[i] //= math.prod(mesh.shape[name] for name in names)
    return tuple(local)


def shard_map(run: Callable, mesh, in_specs: Any, out_specs: Any) -> Callable:
    """``jax.shard_map(run, mesh=mesh, in_specs=in_specs, out_specs=out_specs,
    check_vma=False)`` (the solvers linearise inside, which the varying-axis types reject), with
    the inputs' zero-size arrays made inside instead of passed (see the module's docstring).
    ``in_specs``: a prefix of the arguments' tuple, as ``jax.shard_map`` takes it."""

    def mapped(*args):
        bare = isinstance(in_specs, PartitionSpec) or in_specs is None
        specs = (in_specs,) * len(args) if bare else tuple(in_specs)
        # one spec per array: a spec applies to every array under its argument
        per_leaf = jax.tree.map(
            lambda spec, arg: jax.tree.map(lambda _: spec, arg),
            specs,
            args,
            is_leaf=lambda x: isinstance(x, PartitionSpec),
        )
        leaves, treedef = jax.tree.flatten(args)
        leaf_specs = jax.tree.leaves(per_leaf, is_leaf=lambda x: isinstance(x, PartitionSpec))
        kept = [i for i, a in enumerate(leaves) if a.size > 0]
        empty = {
            i: (_local_shape(a.shape, s, mesh), a.dtype)
            for i, (a, s) in enumerate(zip(leaves, leaf_specs, strict=True))
            if a.size == 0
        }

        def inner(*values):
            full, it = [], iter(values)
            for i in range(len(leaves)):
                full.append(jnp.zeros(*empty[i]) if i in empty else next(it))
            return run(*jax.tree.unflatten(treedef, full))

        return jax.shard_map(
            inner,
            mesh=mesh,
            in_specs=tuple(leaf_specs[i] for i in kept),
            out_specs=out_specs,
            check_vma=False,
        )(*(leaves[i] for i in kept))

    return mapped
