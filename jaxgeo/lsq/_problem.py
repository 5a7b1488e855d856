"""The adjustment problem as arrays: parameter groups, observations, and their sparsity structure.

Unknowns ``y = (z, u)``:

- ``z``: per group ``(n_blocks, n_params)``, the camera parameters as ``theta = theta0 + scale * z``
  (``scale`` from the initial normal equations, so that every ``z`` has a unit effect);
- ``u``: ``(n_points, 3)`` ground points in metres, ``ground = origin + u / metres_per_unit``:
  a linear rescaling of ``(lon_deg, lat_deg, h_m)`` whose axes are east, north, up at ``origin``
  (so the 3x3 point covariances are in local ENU metres).

Observations (:mod:`~jaxgeo.lsq._observations`): image points (each of one block of one
group, and one ground point), GCP coordinates (each of one ground point; sigma per ENU axis,
``inf`` for an unobserved axis), and per-block priors (the models' own ``prior_residuals`` and
optional parameter priors); parameter blocks of one structure are stacked in a :class:`ModelGroup`.
Every observation touches one camera block and/or one point: :class:`Structure` records which,
for the Schur-complement descent.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Float, Int, PyTree

from .._runtime.arrays import device_array
from ._band import block_bandwidth, super_blocks
from ._observations import GroundObs, ImageObs


class ModelGroup(eqx.Module):
    """Parameter blocks of one structure, stacked leaf-wise (leading axis = block).

    Fields:
        static: the non-adjusted part, array leaves stacked (``eqx.combine`` with the dynamic).
        theta0: ``(n_blocks, n_params)`` initial values of the adjustable leaves, raveled.
        names: per block, the image names it serves (one unless a multi-image model).
        param_names: per raveled parameter, its leaf path (``.bias.shift_px[0]``).
    """

    static: PyTree
    theta0: Float[Array, "n p"]
    dyn_treedef: Any = eqx.field(static=True)
    dyn_shapes: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    names: tuple[tuple[str, ...], ...] = eqx.field(static=True)
    multi: bool = eqx.field(static=True)
    param_names: tuple[str, ...] = eqx.field(static=True)

    @property
    def n_blocks(self) -> int:
        return len(self.names)

    @property
    def n_params(self) -> int:
        return int(sum(int(np.prod(s)) for s in self.dyn_shapes))

    @property
    def n_slots(self) -> int:
        return len(self.names[0])

    def unravel(self, theta: Float[Array, "n p"]) -> PyTree:
        """Raveled parameters ``(n, p)`` -> the stacked dynamic pytree."""
        leaves, start = [], 0
        for shape in self.dyn_shapes:
            size = int(np.prod(shape))
            leaves.append(theta[:, start : start + size].reshape(theta.shape[0], *shape))
            start += size
        return jax.tree.unflatten(self.dyn_treedef, leaves)

    def blocks(self, theta: Float[Array, "n p"]) -> PyTree:
        """The stacked blocks with parameters ``theta``."""
        return eqx.combine(self.unravel(theta), self.static)

    def image_model(self, block: Any, slot: int):
        """The sensor model of image ``slot`` of one (unstacked) block."""
        return block.image(slot) if self.multi else block

    def block_at(self, theta: Float[Array, "n p"], k: int) -> Any:
        """Block ``k`` (unstacked) with concrete parameters ``theta`` (Python level: numpy
        slicing, no XLA dispatch)."""
        theta = np.asarray(theta)
        leaves, start = [], 0
        for shape in self.dyn_shapes:
            size = int(np.prod(shape))
            leaves.append(device_array(theta[k, start : start + size].reshape(shape)))
            start += size
        dyn = jax.tree.unflatten(self.dyn_treedef, leaves)
        static = jax.tree.map(
            lambda x: device_array(np.asarray(x)[k]) if eqx.is_array(x) else x, self.static
        )
        return eqx.combine(dyn, static)


class Structure(eqx.Module):
    """Sparsity of the normal equations (all image observations concatenated, group-slot order).

    ``obs_params`` (M, P): global indices of the parameters an observation depends on, padded
    with ``n_params`` (a dummy slot); ``obs_point`` (M,); ``block_params``: per group
    ``(n_blocks, P)``; ``pair_a, pair_b`` (K,): every ordered pair of observations of one point,
    ``pair_point`` (K,) that point; ``ground_point`` (c,) the point of each ground observation.

    For assembling the normal equations without scalar scatter-adds (slow on CPU: one atomic
    add per element of ``(M, P, P)``), the blocks are also numbered globally: ``obs_block``
    (M,) the global block of each observation, ``all_block_params`` (B, P) the parameter
    indices of every block (groups in order), ``pair_blocks`` (Q, 2) the distinct (block of
    ``a``, block of ``b``) of the pairs and ``pair_seg`` (K,) the index of a pair's among them:
    products are summed per block (pair) first (``segment_sum``), then added to the matrix.

    ``band``: 0, or the number of parameter blocks per super-block when the reduced camera
    system is solved as a block-banded matrix (:mod:`~jaxgeo.lsq._band`: one group whose
    blocks share points only with blocks a few places away, e.g. a strip's sub-scenes).
    """

    obs_params: Int[Array, "M P"]
    obs_point: Int[Array, " M"]
    ground_point: Int[Array, " c"]
    block_params: tuple[Int[Array, "n P"], ...]
    pair_a: Int[Array, " K"]
    pair_b: Int[Array, " K"]
    pair_point: Int[Array, " K"]
    obs_block: Int[Array, " M"]
    all_block_params: Int[Array, "B P"]
    pair_blocks: Int[Array, "Q 2"]
    pair_seg: Int[Array, " K"]
    n_params: int = eqx.field(static=True)
    width: int = eqx.field(static=True)
    n_points: int = eqx.field(static=True)
    group_shapes: tuple[tuple[int, int], ...] = eqx.field(static=True)
    band: int = eqx.field(static=True, default=0)

    @property
    def n_blocks(self) -> int:
        return sum(b for b, _ in self.group_shapes)


class Problem(eqx.Module):
    """A bundle adjustment as arrays; a pure input of :func:`jaxgeo.lsq.solve`.

    ``n_rows``: number of scalar observations (image, ground with non-zero weight, priors), an
    array (not static): problems that differ only in which points are GCPs share one compiled
    solve and stack for ``vmap``. The loss and the solver's settings are not part of the
    problem (see :class:`~jaxgeo.lsq.SolverConfig`).
    """

    groups: tuple[ModelGroup, ...]
    images: tuple[ImageObs, ...]
    ground: GroundObs
    origin: Float[Array, "n 3"]
    metres_per_unit: Float[Array, "n 3"]
    prior_mean: tuple[Float[Array, "b p"], ...]
    prior_weight: tuple[Float[Array, "b p"], ...]
    structure: Structure
    n_rows: Int[Array, ""]

    @property
    def n_unknowns(self) -> int:
        return self.structure.n_params + 3 * self.structure.n_points

    @property
    def redundancy(self) -> Int[Array, ""]:
        return self.n_rows - self.n_unknowns

    def ground_points(self, u: Float[Array, "n 3"]) -> Float[Array, "n 3"]:
        """Unknowns ``u`` (m) -> ``(lon_deg, lat_deg, h_m)``."""
        return self.origin + u / self.metres_per_unit

    def with_xy(self, xy: Float[Array, "M 2"]) -> Problem:
        """The same problem with other image measurements (all blocks concatenated, in order)."""
        sizes = np.cumsum([0] + [ob.xy.shape[0] for ob in self.images])
        parts = tuple(xy[a:b] for a, b in zip(sizes[:-1], sizes[1:], strict=True))
        return eqx.tree_at(lambda p: tuple(ob.xy for ob in p.images), self, parts)


def _index(a) -> Int[Array, "..."]:
    """An index array of :class:`Structure` as int32: half the memory of int64 (a 200 000-
    observation pair holds ~30 MB of them, and XLA converts gather indices to 32 bits anyway)."""
    a = np.asarray(a)
    if a.size and a.max() >= np.iinfo(np.int32).max:
        raise ValueError(f"too many unknowns or observations for 32-bit indices ({a.max()})")
    return device_array(a, np.int32)


def make_structure(
    groups: tuple[ModelGroup, ...],
    images: tuple[ImageObs, ...],
    ground: GroundObs,
    n_points: int,
) -> Structure:
    """Index arrays of :class:`Structure` from the groups and observation blocks (numpy)."""
    sizes = [g.n_blocks * g.n_params for g in groups]
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    n_params = int(offsets[-1])
    width = max([g.n_params for g in groups], default=0)

    def param_index(g: int, blocks: np.ndarray) -> np.ndarray:
        p = groups[g].n_params
        idx = np.full((blocks.shape[0], width), n_params, dtype=np.int64)
        idx[:, :p] = offsets[g] + blocks[:, None] * p + np.arange(p)[None, :]
        return idx

    obs_params = [param_index(ob.group, np.asarray(ob.block)) for ob in images]
    obs_point = np.concatenate([np.asarray(ob.point) for ob in images]).astype(np.int64)
    obs_params = np.concatenate(obs_params) if obs_params else np.zeros((0, width), dtype=np.int64)
    block_params = tuple(
        _index(param_index(g, np.arange(grp.n_blocks))) for g, grp in enumerate(groups)
    )
    pair_a, pair_b = observation_pairs(obs_point, n_points)
    block_offsets = np.concatenate([[0], np.cumsum([g.n_blocks for g in groups])]).astype(int)
    obs_block = [block_offsets[ob.group] + np.asarray(ob.block) for ob in images]
    obs_block = np.concatenate(obs_block).astype(np.int64) if obs_block else np.zeros(0, int)
    all_params = [param_index(g, np.arange(grp.n_blocks)) for g, grp in enumerate(groups)]
    all_params = np.concatenate(all_params) if all_params else np.zeros((0, width), np.int64)
    pairs = np.stack([obs_block[pair_a], obs_block[pair_b]], axis=1).reshape(-1, 2)
    pair_blocks, pair_seg = np.unique(pairs, axis=0, return_inverse=True)
    band = 0
    if len(groups) == 1:
        bandwidth = block_bandwidth(pair_blocks)
        band = super_blocks(groups[0].n_blocks, groups[0].n_params, bandwidth)
    return Structure(
        obs_params=_index(obs_params),
        obs_point=_index(obs_point),
        ground_point=_index(ground.point),
        block_params=block_params,
        pair_a=_index(pair_a),
        pair_b=_index(pair_b),
        pair_point=_index(obs_point[pair_a]),
        obs_block=_index(obs_block),
        all_block_params=_index(all_params),
        pair_blocks=_index(pair_blocks.reshape(-1, 2)),
        pair_seg=_index(pair_seg.reshape(-1)),
        n_params=n_params,
        width=width,
        n_points=n_points,
        group_shapes=tuple((g.n_blocks, g.n_params) for g in groups),
        band=band,
    )


def observation_pairs(point: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Every ordered pair ``(a, b)`` of observations of the same point (``a == b`` included)."""
    point = np.asarray(point, dtype=np.int64)
    order = np.argsort(point, kind="stable")
    count = np.bincount(point, minlength=n_points)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    reps = count[point]
    a = np.repeat(np.arange(point.shape[0]), reps)
    first = np.concatenate([[0], np.cumsum(reps)[:-1]])
    within = np.arange(a.shape[0]) - np.repeat(first, reps)
    b = order[start[point[a]] + within]
    return a, b
