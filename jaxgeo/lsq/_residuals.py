"""The residuals of a :class:`~jaxgeo.lsq.Problem` and their Jacobian blocks.

:func:`residuals` is the objective (image, ground and prior residuals, weighted). :func:`jacobians`
gives its non-zero Jacobian blocks (:class:`~._schur.Jacobians`) with the image observations
linearised :data:`CHUNK` at a time (per block, when they are sorted by block) and written in
place: linearising the whole objective at once, as :func:`~._schur.split_jacobians` does for any
function, holds every intermediate of the sensor models -- an RPC's polynomial terms and their
tangents -- for all observations together. In the solve of a 200 000-observation pair (an RPC
pair with affine biases) XLA's working memory went from 393 to 256 MB with these chunks. Each
image observation depends on one block's parameters and one point, so a chunk's blocks come
from the same colouring (``width`` tangents in the parameters, 3 in the chunk's points) applied
to its observations alone.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._ground import enu_residuals
from ._loss import robust
from ._problem import Problem
from ._schur import Jacobians

CHUNK = 1 << 13
"""Image observations (per block, for block-sorted observations) linearised at a time by
:func:`jacobians`."""


def _take(tree, index):
    return jax.tree.map(lambda x: x[index] if eqx.is_array(x) else x, tree)


def _block_priors(block) -> Float[Array, " q"]:
    return jnp.asarray(block.prior_residuals(), dtype=float).reshape(-1)


def _padded_layout(
    block_start: tuple[int, ...], most: int | None = None
) -> tuple[Int[Array, "b k"], Int[Array, " m"]]:
    """Layout of block-sorted observations padded to ``(n_blocks, most)`` (default: the largest
    block's count): the index of each padded entry into the observations (a block's last one
    repeated; 0 for an empty block), and the padded position of each observation. Computed in
    the program from the (static) block starts, not baked in as constants of the observations'
    size: the program, its compilation and its serialized export stay small however many
    observations there are."""
    start = np.asarray(block_start)
    counts = np.diff(start)
    most = max(int(counts.max()), 1) if most is None else int(most)
    first, count = jnp.asarray(start[:-1])[:, None], jnp.asarray(counts)[:, None]
    rank = jnp.arange(most)[None, :]
    index = jnp.where(count > 0, first + jnp.minimum(rank, jnp.maximum(count - 1, 0)), 0)
    obs = jnp.arange(int(start[-1]))
    block = jnp.searchsorted(jnp.asarray(start[1:]), obs, side="right")
    position = block * most + (obs - jnp.asarray(start[:-1])[block])
    return index, position


def _per_block(grp, stacked, ob, ground: Float[Array, "n 3"]) -> Float[Array, "m 2"]:
    """Weighted image residuals of ``ob`` (sorted by block, ``ob.block_start``): each block's
    model projects its own observations, padded to the largest block's count and vmapped over
    the blocks (one program whatever the number of blocks; no per-observation model copy)."""
    index, position = _padded_layout(ob.block_start)

    def project(block, g, slot=ob.slot):
        return grp.image_model(block, slot).project(g)

    xy = eqx.filter_vmap(project, in_axes=(eqx.if_array(0), 0))(stacked, ground[ob.point[index]])
    return (xy.reshape(-1, 2)[position] - ob.xy) * ob.weight[:, None]


def _per_observation(grp, stacked, ob, index, ground) -> Float[Array, "k 2"]:
    """Weighted image residuals of the observations ``index`` (k,) of ``ob`` (``None``: all),
    at their points ``ground`` (k, 3): each with its own copy of its block's model."""

    def one(block, g, xy, w, slot=ob.slot):
        return (grp.image_model(block, slot).project(g) - xy) * w

    block, xy, w = (ob.block, ob.xy, ob.weight) if index is None else (
        ob.block[index], ob.xy[index], ob.weight[index])  # fmt: skip
    return eqx.filter_vmap(one, in_axes=(eqx.if_array(0), 0, 0, 0))(
        _take(stacked, block), ground, xy, w
    )


def thetas(problem: Problem, z, scales) -> tuple[Float[Array, "b p"], ...]:
    """Solver variables ``z`` -> raveled parameters per group."""
    return tuple(g.theta0 + sc * zg for g, sc, zg in zip(problem.groups, scales, z, strict=True))


def _stacked(problem: Problem, z, scales) -> tuple:
    theta = thetas(problem, z, scales)
    return tuple(g.blocks(t) for g, t in zip(problem.groups, theta, strict=True)), theta


def _ground_and_priors(problem: Problem, u, ground, stacked, theta, loss: str, loss_scale):
    gnd = robust(enu_residuals(problem, u, ground) * problem.ground.weight, loss, loss_scale)
    prior = []
    for grp, blocks, th, mean, wt in zip(
        problem.groups, stacked, theta, problem.prior_mean, problem.prior_weight, strict=True
    ):
        own = eqx.filter_vmap(_block_priors, in_axes=eqx.if_array(0))(blocks)
        own = own.reshape(grp.n_blocks, -1)
        user = (th - mean) * wt if mean.shape[1] else jnp.zeros((grp.n_blocks, 0))
        prior.append(jnp.concatenate([own, user], axis=1))
    return gnd, tuple(prior)


def residuals(y, args):
    """Weighted residuals ``(image per observation block, ground, prior per group)``.

    ``y = (z, u)`` (see :mod:`~jaxgeo.lsq._problem`); ``args = (problem, scales, loss,
    loss_scale)``: the loss (``"l2"``, ``"huber"``, ``"cauchy"``) on the image and ground
    residuals (per observation: an image point's 2-vector, a GCP's 3-vector).
    """
    problem, scales, loss, loss_scale = args
    z, u = y
    ground = problem.ground_points(u)
    stacked, theta = _stacked(problem, z, scales)
    img = []
    for ob in problem.images:
        grp = problem.groups[ob.group]
        if ob.block_start:
            r = _per_block(grp, stacked[ob.group], ob, ground)
        else:
            r = _per_observation(grp, stacked[ob.group], ob, None, ground[ob.point])
        img.append(robust(r, loss, loss_scale))
    gnd, prior = _ground_and_priors(problem, u, ground, stacked, theta, loss, loss_scale)
    return tuple(img), gnd, prior


def _colours(width: int, like: Array) -> Array:
    """``width`` tangents of ``like`` (b, p): tangent ``i`` is 1 at parameter ``i`` of every
    block (0 beyond ``p``)."""
    eye = jnp.eye(width, dtype=like.dtype)
    return jnp.broadcast_to(eye[:, None, : like.shape[1]], (width, *like.shape))


def _image_blocks(problem: Problem, scales, y, ob, loss: str, loss_scale):
    """``(r, jc, jp)`` of the image observations ``ob``: (m, 2), (m, 2, width), (m, 2, 3),
    linearised :data:`CHUNK` observations (per block) at a time."""
    z, u = y
    g, width = ob.group, problem.structure.width
    grp = problem.groups[g]
    m = int(ob.xy.shape[0])
    if m == 0:
        return jnp.zeros((0, 2)), jnp.zeros((0, 2, width)), jnp.zeros((0, 2, 3))
    # per chunk: the observations evaluated (B, k) or (k,) (padding repeats one) and where
    # each result goes (``m`` for padding: dropped)
    if ob.block_start:
        counts = np.diff(np.asarray(ob.block_start))
        most = max(int(counts.max()), 1)
        k = min(most, CHUNK)
        n_chunks = -(-most // k)
        index, _ = _padded_layout(ob.block_start, n_chunks * k)
        real = jnp.arange(n_chunks * k)[None, :] < jnp.asarray(counts)[:, None]
        dest = jnp.where(real, index, m)
        split = lambda a: jnp.moveaxis(a.reshape(a.shape[0], n_chunks, k), 1, 0)  # noqa: E731
        chunks, dests = split(index), split(dest)  # (C, B, k)
    else:
        k = min(m, CHUNK)
        n_chunks = -(-m // k)
        flat = jnp.arange(n_chunks * k)
        chunks = jnp.minimum(flat, m - 1).reshape(n_chunks, k)
        dests = jnp.where(flat < m, flat, m).reshape(n_chunks, k)

    def chunk(idx):  # (B, k) or (k,) observation indices
        pts = ob.point[idx]
        origin, mpu = problem.origin[pts], problem.metres_per_unit[pts]

        def res(zg, uu):
            zz = tuple(zg if i == g else zi for i, zi in enumerate(z))
            stacked, _ = _stacked(problem, zz, scales)
            ground = origin + uu / mpu
            if ob.block_start:

                def project(block, gr, slot=ob.slot):
                    return grp.image_model(block, slot).project(gr)

                xy = eqx.filter_vmap(project, in_axes=(eqx.if_array(0), 0))(stacked[g], ground)
                r = (xy - ob.xy[idx]) * ob.weight[idx][..., None]
            else:
                r = _per_observation(grp, stacked[g], ob, idx, ground)
            return robust(r.reshape(-1, 2), loss, loss_scale).reshape(r.shape)

        uu = u[pts]
        r, lin_z = jax.linearize(lambda zg: res(zg, uu), z[g])
        _, lin_u = jax.linearize(lambda v: res(z[g], v), uu)
        us = jnp.broadcast_to(jnp.eye(3, dtype=u.dtype).reshape(3, *([1] * (uu.ndim - 1)), 3),
                              (3, *uu.shape))  # fmt: skip
        jc = jnp.moveaxis(jax.vmap(lin_z)(_colours(width, z[g])), 0, -1)
        jp = jnp.moveaxis(jax.vmap(lin_u)(us), 0, -1)
        return r, jc, jp

    if n_chunks == 1:  # a small problem (each of a batch): no loop, no scatter
        out = chunk(chunks[0])
        if ob.block_start:
            _, position = _padded_layout(ob.block_start, k)
            return tuple(a.reshape(a.shape[0] * k, *a.shape[2:])[position] for a in out)
        return out

    def body(c, acc):  # each chunk's blocks written in place (no stacked copy of them)
        d = dests[c].reshape(-1)
        return tuple(
            a.at[d].set(v.reshape(d.shape[0], *a.shape[1:]), mode="drop")
            for a, v in zip(acc, chunk(chunks[c]), strict=True)
        )

    # the buffers come into being with the point they linearise at (a zero broadcast has no
    # operand, and XLA may schedule it at the start of the program: the solve's final
    # linearisation then held 28 MB of a 200 000-observation pair through the whole solve)
    zero = 0.0 * u.reshape(-1)[0]
    init = tuple(jnp.full(shape, zero) for shape in ((m, 2), (m, 2, width), (m, 2, 3)))
    return jax.lax.fori_loop(0, n_chunks, body, init)


def jacobians(problem: Problem, scales, y, loss: str = "l2", loss_scale: float = 3.0) -> Jacobians:
    """The non-zero Jacobian blocks of :func:`residuals` at ``y`` (the image observations
    :data:`CHUNK` at a time; see the module docstring)."""
    z, u = y
    width = problem.structure.width

    def rest(zz, uu):
        stacked, theta = _stacked(problem, zz, scales)
        return _ground_and_priors(
            problem, uu, problem.ground_points(uu), stacked, theta, loss, loss_scale
        )

    (gnd, pr), lin_z = jax.linearize(lambda zz: rest(zz, u), z)
    _, lin_u = jax.linearize(lambda uu: rest(z, uu), u)
    zs = tuple(_colours(width, zg) for zg in z)
    us = jnp.broadcast_to(jnp.eye(3, dtype=u.dtype)[:, None, :], (3, *u.shape))
    _, pr_z = jax.vmap(lin_z)(zs)
    gnd_u, _ = jax.vmap(lin_u)(us)
    parts = [_image_blocks(problem, scales, y, ob, loss, loss_scale) for ob in problem.images]
    last = lambda o: jnp.moveaxis(o, 0, -1)  # noqa: E731
    cat = lambda i, shape: jnp.concatenate([p[i] for p in parts]) if parts else jnp.zeros(shape)  # noqa: E731
    return Jacobians(
        jc=cat(1, (0, 2, width)),
        jp=cat(2, (0, 2, 3)),
        r=cat(0, (0, 2)),
        jg=last(gnd_u),
        rg=gnd,
        jpr=tuple(last(o) for o in pr_z),
        rpr=tuple(pr),
    )
