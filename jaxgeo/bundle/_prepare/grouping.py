"""Grouping: adjustable parameters (filters), parameter blocks, stacking blocks of one structure.

A *parameter block* is what one set of camera parameters belongs to: a sensor model (one image),
or a multi-image model such as :class:`~jaxgeo.models._kepler.KeplerSequence` whose ``image(i)``
views share one orbit (given to :func:`jaxgeo.adjust` under a tuple of image names).
Which leaves of a block are adjusted is an equinox filter spec (``eqx.partition``), never a copy;
without one, the model's own ``adjustable_filter()``.

Blocks of the same pytree structure (same treedef, leaf shapes and filter) are stacked leaf-wise
into one :class:`~jaxgeo.lsq.ModelGroup`, so that 80 scenes cost one ``vmap``, not
80 Python-level traces.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import PyTree

from ..._runtime.arrays import device_array
from ...lsq import ModelGroup
from .._errors import AdjustmentError


def leaf_names(tree: PyTree) -> list[str]:
    """``keystr`` paths of the leaves, expanded to one name per array element."""
    names = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        base = jax.tree_util.keystr(path)
        shape = np.shape(leaf)
        if int(np.prod(shape)) == 1 and len(shape) == 0:
            names.append(base)
            continue
        for flat in range(int(np.prod(shape))):
            idx = np.unravel_index(flat, shape)
            names.append(f"{base}[{','.join(str(int(i)) for i in idx)}]")
    return names


def hashable_key(value: Any):
    try:
        hash(value)
        return (type(value).__name__, value)
    except TypeError:
        return (type(value).__name__, repr(value))


def partition_block(block: Any, spec: Any, where: str) -> tuple[PyTree, PyTree]:
    """``eqx.partition(block, spec)`` checking that every selected leaf is a float array."""
    spec = block.adjustable_filter() if spec is None else spec
    try:
        dynamic, static = eqx.partition(block, spec)
    except Exception as err:  # a malformed spec: say whose
        raise AdjustmentError(f"{where}: filter spec does not match the model: {err}") from None
    for path, leaf in jax.tree_util.tree_flatten_with_path(dynamic)[0]:
        if not eqx.is_inexact_array(leaf):
            raise AdjustmentError(
                f"{where}: filter selects {jax.tree_util.keystr(path)} = {leaf!r}, which is not a "
                "floating-point array and cannot be adjusted"
            )
    return dynamic, static


def signature(dynamic: PyTree, static: PyTree, n_images: int) -> tuple:
    """Blocks with equal signatures can be stacked into one group."""
    d_leaves, d_tree = jax.tree.flatten(dynamic)
    s_leaves, s_tree = jax.tree.flatten(static)
    d_sig = tuple((np.shape(x), jnp.result_type(x)) for x in d_leaves)
    s_sig = tuple(
        ("array", np.shape(x), jnp.result_type(x)) if eqx.is_array(x) else hashable_key(x)
        for x in s_leaves
    )
    return (n_images, d_tree, s_tree, d_sig, s_sig)


def ravel_stacked(dynamic_leaves: Sequence[Any], n: int) -> np.ndarray:
    """Stacked leaves ``(n, ...)`` -> ``(n, p)`` (numpy)."""
    if not dynamic_leaves:
        return np.zeros((n, 0))
    return np.concatenate([np.reshape(np.asarray(x), (n, -1)) for x in dynamic_leaves], axis=1)


def make_group(
    parts: Sequence[tuple[PyTree, PyTree]], names: Sequence[tuple[str, ...]], multi: bool
) -> ModelGroup:
    """Stack blocks of one signature (see :func:`signature`) into a :class:`ModelGroup`."""
    n = len(parts)
    d_leaves = [jax.tree.leaves(d) for d, _ in parts]
    d_tree = jax.tree.structure(parts[0][0])
    s_leaves = [jax.tree.flatten(s)[0] for _, s in parts]
    s_tree = jax.tree.structure(parts[0][1])
    stacked_s = []
    for column in zip(*s_leaves, strict=True):
        if eqx.is_array(column[0]):
            stacked_s.append(device_array(np.stack([np.asarray(c) for c in column])))
        else:
            stacked_s.append(column[0])
    stacked_d = [
        np.stack([np.asarray(c, dtype=float) for c in column])
        for column in zip(*d_leaves, strict=True)
    ]
    theta0 = device_array(ravel_stacked(stacked_d, n))
    return ModelGroup(
        static=jax.tree.unflatten(s_tree, stacked_s),
        theta0=theta0,
        dyn_treedef=d_tree,
        dyn_shapes=tuple(tuple(np.shape(x)) for x in d_leaves[0]) if d_leaves[0] else (),
        names=tuple(tuple(nm) for nm in names),
        multi=multi,
        param_names=tuple(leaf_names(parts[0][0])),
    )


def shared_leaves(parts: Sequence[tuple[PyTree, PyTree]], labels: Sequence[str]) -> list[str]:
    """Labels of blocks whose adjustable leaves are the very same arrays as another block's."""
    owner: dict[int, str] = {}
    clashes = []
    for (dynamic, _), label in zip(parts, labels, strict=True):
        for leaf in jax.tree.leaves(dynamic):
            other = owner.setdefault(id(leaf), label)
            if other != label:
                clashes.append(f"{other!r} and {label!r}")
    return sorted(set(clashes))


def per_key(value: Any, key: Any, default: Any = None) -> Any:
    """A per-model option given once for all models or as a mapping keyed by model key."""
    if isinstance(value, Mapping):
        return value.get(key, default)
    return default if value is None else value
