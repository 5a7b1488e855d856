"""The adjustment problem as arrays: parameter groups, observations, and their sparsity structure.

Unknowns ``y = (z, u)``:

- ``z``: per group ``(n_blocks, n_params)``, the camera parameters as ``theta = theta0 + scale * z``
  (``scale`` from the initial normal equations, so that every ``z`` has a unit effect);
- ``u``: ``(n_points, 3)`` ground points in metres, ``ground = origin + u / metres_per_unit``:
  a linear rescaling of ``(lon_deg, lat_deg, h_m)`` whose axes are east, north, up at ``origin``
  (so the 3x3 point covariances are in local ENU metres).

Observations: image points (each of one block of one group, and one ground point), GCP
coordinates (each of one ground point; sigma per ENU axis, ``inf`` for an unobserved axis),
and per-block priors (the models' own ``prior_residuals`` and optional parameter priors).
Every observation touches one camera block and/or one point: :class:`Structure` records which,
for the Schur-complement descent.
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .. import geodesy
from .params import ModelGroup

Loss = Literal["l2", "huber", "cauchy"]
LOSSES = ("l2", "huber", "cauchy")


class ImageObs(eqx.Module):
    """Image measurements of image ``slot`` of the blocks of group ``group``.

    ``block`` (m,) block index in the group, ``point`` (m,) ground point index, ``xy`` (m, 2) px,
    ``weight`` (m,) = 1 / sigma_px.
    """

    block: Int[Array, " m"]
    point: Int[Array, " m"]
    xy: Float[Array, "m 2"]
    weight: Float[Array, " m"]
    group: int = eqx.field(static=True)
    slot: int = eqx.field(static=True)


class GroundObs(eqx.Module):
    """Ground-coordinate observations: ``point`` (c,), ``lonlath`` (c, 3), ``weight`` (c, 3) =
    1/sigma per east/north/up axis in metres (0 for an axis without observation)."""

    point: Int[Array, " c"]
    lonlath: Float[Array, "c 3"]
    weight: Float[Array, "c 3"]


class Structure(eqx.Module):
    """Sparsity of the normal equations (all image observations concatenated, group-slot order).

    ``obs_params`` (M, P): global indices of the parameters an observation depends on, padded
    with ``n_params`` (a dummy slot); ``obs_point`` (M,); ``block_params``: per group
    ``(n_blocks, P)``; ``pair_a, pair_b`` (K,): every ordered pair of observations of one point,
    ``pair_point`` (K,) that point; ``ground_point`` (c,) the point of each ground observation.
    """

    obs_params: Int[Array, "M P"]
    obs_point: Int[Array, " M"]
    ground_point: Int[Array, " c"]
    block_params: tuple[Int[Array, "n P"], ...]
    pair_a: Int[Array, " K"]
    pair_b: Int[Array, " K"]
    pair_point: Int[Array, " K"]
    n_params: int = eqx.field(static=True)
    width: int = eqx.field(static=True)
    n_points: int = eqx.field(static=True)
    group_shapes: tuple[tuple[int, int], ...] = eqx.field(static=True)


class Problem(eqx.Module):
    """A bundle adjustment as arrays; a pure input of :func:`jaxgeo.adjust.core.solve`."""

    groups: tuple[ModelGroup, ...]
    images: tuple[ImageObs, ...]
    ground: GroundObs
    origin: Float[Array, "n 3"]
    metres_per_unit: Float[Array, "n 3"]
    prior_mean: tuple[Float[Array, "b p"], ...]
    prior_weight: tuple[Float[Array, "b p"], ...]
    structure: Structure
    n_rows: int = eqx.field(static=True)
    loss: str = eqx.field(static=True, default="l2")
    loss_scale: float = eqx.field(static=True, default=3.0)

    @property
    def n_unknowns(self) -> int:
        return self.structure.n_params + 3 * self.structure.n_points

    @property
    def redundancy(self) -> int:
        return self.n_rows - self.n_unknowns

    def ground_points(self, u: Float[Array, "n 3"]) -> Float[Array, "n 3"]:
        """Unknowns ``u`` (m) -> ``(lon_deg, lat_deg, h_m)``."""
        return self.origin + u / self.metres_per_unit

    def with_xy(self, xy: Float[Array, "M 2"]) -> Problem:
        """The same problem with other image measurements (all blocks concatenated, in order)."""
        sizes = np.cumsum([0] + [ob.xy.shape[0] for ob in self.images])
        parts = tuple(xy[a:b] for a, b in zip(sizes[:-1], sizes[1:], strict=True))
        return eqx.tree_at(lambda p: tuple(ob.xy for ob in p.images), self, parts)


def metres_per_unit(lonlath: Float[Array, "n 3"]) -> Float[Array, "n 3"]:
    """Metres per degree of longitude, per degree of latitude, and 1 per metre of height."""
    lonlath = jnp.asarray(lonlath, dtype=float)
    lat = jnp.deg2rad(lonlath[..., 1])
    h = lonlath[..., 2]
    w = jnp.sqrt(1.0 - geodesy.WGS84_E2 * jnp.sin(lat) ** 2)
    n_radius = geodesy.WGS84_A_M / w
    m_radius = geodesy.WGS84_A_M * (1.0 - geodesy.WGS84_E2) / w**3
    k = jnp.pi / 180.0
    return jnp.stack(
        [k * (n_radius + h) * jnp.cos(lat), k * (m_radius + h), jnp.ones_like(h)], axis=-1
    )


def metres_per_unit_np(lonlath) -> np.ndarray:
    """:func:`metres_per_unit` in numpy (Python-level set-up, no XLA dispatch)."""
    lonlath = np.asarray(lonlath, dtype=float)
    lat = np.deg2rad(lonlath[..., 1])
    h = lonlath[..., 2]
    w = np.sqrt(1.0 - geodesy.WGS84_E2 * np.sin(lat) ** 2)
    n_radius = geodesy.WGS84_A_M / w
    m_radius = geodesy.WGS84_A_M * (1.0 - geodesy.WGS84_E2) / w**3
    k = np.pi / 180.0
    return np.stack([k * (n_radius + h) * np.cos(lat), k * (m_radius + h), np.ones_like(h)], -1)


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
        jnp.asarray(param_index(g, np.arange(grp.n_blocks))) for g, grp in enumerate(groups)
    )
    pair_a, pair_b = observation_pairs(obs_point, n_points)
    return Structure(
        obs_params=jnp.asarray(obs_params),
        obs_point=jnp.asarray(obs_point),
        ground_point=jnp.asarray(ground.point),
        block_params=block_params,
        pair_a=jnp.asarray(pair_a),
        pair_b=jnp.asarray(pair_b),
        pair_point=jnp.asarray(obs_point[pair_a]),
        n_params=n_params,
        width=width,
        n_points=n_points,
        group_shapes=tuple((g.n_blocks, g.n_params) for g in groups),
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
