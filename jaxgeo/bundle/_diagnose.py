"""Diagnosis on the host: which parameters or points the normal equations do not determine.

A ground point is undetermined when its 3x3 block ``V`` (image rays plus ground observations) is
singular: one ray, parallel rays. Camera parameters are undetermined when the reduced camera
system ``S = U - W V^-1 W^T`` is singular: the eigenvectors of its (Jacobi-scaled) null space
name them, e.g. a common shift of all images with no GCP.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..lsq import Band, Problem, blocks_at, initial_unknowns, unit_scales
from ..lsq.internal import reduced_system

SINGULAR_RTOL = 1e-10
"""Eigenvalues below this fraction of the largest (after unit-diagonal scaling) are zero."""


@eqx.filter_jit
def _normal_matrices(problem: Problem, y, loss: str, loss_scale: float):
    _, blocks = blocks_at(problem, unit_scales(problem), y, loss, loss_scale)
    big_s, _ = reduced_system(blocks, problem.structure, 0.0)
    if isinstance(big_s, Band):  # diagnostics only: the dense matrix, dummy row last
        big_s = jnp.pad(big_s.todense(), ((0, 1), (0, 1)))
    return blocks.v, big_s, blocks.w


def _singular_points(v: np.ndarray, rtol: float) -> list[int]:
    """Points whose (unit-diagonal scaled) 3x3 block is singular, vectorised."""
    if v.shape[0] == 0:
        return []
    d = np.diagonal(v, axis1=1, axis2=2)
    ok = np.all(d > 0, axis=1) & np.all(np.isfinite(v), axis=(1, 2))
    safe = np.where(ok[:, None], d, 1.0)
    scaled = np.where(ok[:, None, None], v / np.sqrt(safe[:, :, None] * safe[:, None, :]), 1.0)
    scaled = np.where(ok[:, None, None], scaled, np.eye(3))
    ev = np.linalg.eigvalsh(scaled)
    bad = ~ok | (ev[:, 0] < rtol * ev[:, -1])
    return [int(j) for j in np.flatnonzero(bad)]


class Direction(eqx.Module):
    """An undetermined direction of the camera parameters (a null vector of ``S``).

    ``params`` (N,): the parameter combination (largest component 1, in parameter units);
    ``point_motion_m`` (3,): RMS over the points of the east, north, up motion (m) that goes
    with a unit step along it (the points absorbing it; zeros when nothing moves).
    """

    params: np.ndarray
    point_motion_m: np.ndarray


def undetermined(
    problem: Problem,
    y=None,
    *,
    loss: str = "l2",
    loss_scale: float = 3.0,
    rtol: float = SINGULAR_RTOL,
) -> tuple[list[int], list[int]]:
    """``(parameter indices, point indices)`` not determined at ``y`` (default: the start).

    ``y = (z, u)`` in the solver's variables with unit scales (``theta - theta0`` and
    metres); ``loss``, ``loss_scale`` as in the solve (:class:`jaxgeo.lsq.SolverConfig`).
    """
    y = y if y is not None else initial_unknowns(problem)
    v, big_s, _ = (np.asarray(x) for x in _normal_matrices(problem, y, loss, float(loss_scale)))
    bad_points = _singular_points(v, rtol)
    n = problem.structure.n_params
    if bad_points or n == 0:
        return [], bad_points
    s = big_s[:n, :n]
    d = np.diag(s).copy()
    zero = [i for i in range(n) if not d[i] > 0]
    if zero:
        return zero, []
    ev, vec = np.linalg.eigh(s / np.sqrt(np.outer(d, d)))
    null = ev < rtol * ev[-1]
    if not np.any(null):
        return [], []
    weight = np.sum(vec[:, null] ** 2, axis=1)
    return [int(i) for i in np.flatnonzero(weight > 1e-2)], []


def directions(
    problem: Problem,
    y=None,
    *,
    loss: str = "l2",
    loss_scale: float = 3.0,
    rtol: float = SINGULAR_RTOL,
    weakest: bool = False,
) -> list[Direction]:
    """The undetermined directions of the camera parameters at ``y`` (arguments as
    :func:`undetermined`), each with the point motion that absorbs it; empty when ``S`` is
    regular (or a point block is singular: :func:`undetermined` names those), unless
    ``weakest``: then the least determined direction (a nearly singular ``S``, e.g. a shift
    that only the terrain relief of the tie points determines)."""
    y = y if y is not None else initial_unknowns(problem)
    v, big_s, w = (np.asarray(x) for x in _normal_matrices(problem, y, loss, float(loss_scale)))
    st = problem.structure
    n = st.n_params
    if n == 0 or _singular_points(v, rtol):
        return []
    s = big_s[:n, :n]
    d = np.diag(s).copy()
    d = np.where(d > 0, d, 1.0)
    ev, vec = np.linalg.eigh(s / np.sqrt(np.outer(d, d)))
    null = ev < rtol * ev[-1]
    if weakest and not null.any():
        null[0] = True
    out = []
    for k in np.flatnonzero(null):
        c = vec[:, k] / np.sqrt(d)
        c = c / c[np.argmax(np.abs(c))]
        c[np.abs(c) < 1e-9] = 0.0
        # the points follow: dp = -V^-1 sum_obs W^T c (W: (M, P, 3))
        cpad = np.concatenate([c, [0.0]])[np.asarray(st.obs_params)]
        rhs = np.zeros((st.n_points, 3))
        np.add.at(rhs, np.asarray(st.obs_point), np.einsum("mpj,mp->mj", w, cpad))
        dp = -np.linalg.solve(v, rhs[..., None])[..., 0] if st.n_points else rhs
        motion = np.sqrt(np.mean(dp**2, axis=0)) if st.n_points else np.zeros(3)
        out.append(Direction(c, motion))
    return out


def explain(direction: Direction, param_names, limit: int = 4) -> str:
    """``direction`` in words: its largest parameters and what absorbs it, e.g. ``aft.bias.
    shift_px[1] (+1) trades against the tie point heights (1 unit moves them 2.1 m up, RMS):
    along-track parallax``."""
    c = np.asarray(direction.params)
    order = [i for i in np.argsort(-np.abs(c)) if abs(c[i]) >= 1e-3][:limit]
    combo = " ".join(f"{c[i]:+.3g} {param_names[i]}" for i in order)
    e, nn, u = (float(x) for x in direction.point_motion_m)
    horiz = float(np.hypot(e, nn))
    if max(horiz, u) < 1e-6:
        what = "no observation sees it (the parameters trade against each other)"
    elif u > 3.0 * horiz:
        what = (
            f"trades against the tie point heights (one unit moves them {u:.3g} m up or down, "
            "RMS): a shift along the epipolar direction is a height change of the points "
            "(along-track parallax)"
        )
    elif horiz > 3.0 * u:
        what = (f"trades against the point positions (one unit moves them {horiz:.3g} m "
                "horizontally, RMS): a common shift of the block")  # fmt: skip
    else:
        what = (f"trades against the point positions ({horiz:.3g} m horizontally, {u:.3g} m in "
                "height per unit, RMS)")  # fmt: skip
    return f"{combo} {what}"
