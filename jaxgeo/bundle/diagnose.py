"""Diagnosis on the host: which parameters or points the normal equations do not determine.

A ground point is undetermined when its 3x3 block ``V`` (image rays plus ground observations) is
singular: one ray, parallel rays. Camera parameters are undetermined when the reduced camera
system ``S = U - W V^-1 W^T`` is singular: the eigenvectors of its (Jacobi-scaled) null space
name them, e.g. a common shift of all images with no GCP.
"""

from __future__ import annotations

import equinox as eqx
import numpy as np

from .problem import Problem
from .schur import reduced_system
from .solve import blocks_at, initial_unknowns, unit_scales

SINGULAR_RTOL = 1e-10
"""Eigenvalues below this fraction of the largest (after unit-diagonal scaling) are zero."""


@eqx.filter_jit
def _normal_matrices(problem: Problem, y, loss: str, loss_scale: float):
    _, blocks = blocks_at(problem, unit_scales(problem), y, loss, loss_scale)
    big_s, _, _ = reduced_system(blocks, problem.structure, 0.0)
    return blocks.v, big_s


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
    metres); ``loss``, ``loss_scale`` as in the solve (:class:`~.config.SolverConfig`).
    """
    y = y if y is not None else initial_unknowns(problem)
    v, big_s = (np.asarray(x) for x in _normal_matrices(problem, y, loss, float(loss_scale)))
    bad_points = []
    for j in range(v.shape[0]):
        d = np.diag(v[j])
        if not np.all(d > 0) or not np.all(np.isfinite(v[j])):
            bad_points.append(j)
            continue
        ev = np.linalg.eigvalsh(v[j] / np.sqrt(np.outer(d, d)))
        if ev[0] < rtol * ev[-1]:
            bad_points.append(j)
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
