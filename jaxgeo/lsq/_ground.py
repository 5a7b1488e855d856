"""Ground-control residuals: the adjusted points in the local east/north/up metres of their
measured coordinates, without a trigonometric call per evaluation.

A point is ``origin + u / metres_per_unit`` (:meth:`~._problem.Problem.ground_points`). Its ECEF
coordinates come from the sines and cosines of its ``origin`` and the offset ``u /
metres_per_unit``, by the angle-addition formulas (:func:`~jaxgeo.geodesy.geodetic_to_ecef_near`:
exact to rounding up to ``geodesy.OFFSET_MAX_RAD`` from the origin); the origins' sines and the
ENU frames of the measured coordinates are computed once per solve (:func:`with_frames`). With
``jnp.sin`` in the residuals, XLA recomputed the sines in every element of the Jacobian's fused
loops: 17 % of the time of the 4000 9-GCP bias problems of ``benchmarks/speed/batch.py``. A point
farther than that from its origin is reported (:func:`beyond_offset`: ``outside_domain``).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .. import geodesy
from ._observations import GroundFrame
from ._problem import Problem


def _offset(problem: Problem, u: Float[Array, "n 3"]) -> Float[Array, "c 2"]:
    """``(dlon, dlat)`` radians of each GCP-observed point from its origin."""
    pt = problem.ground.point
    return jnp.deg2rad(u[pt, :2] / problem.metres_per_unit[pt, :2])


def enu_residuals(
    problem: Problem, u: Float[Array, "n 3"], ground: Float[Array, "n 3"]
) -> Float[Array, "c 3"]:
    """East/north/up metres of the adjusted points ``ground`` (``= problem.ground_points(u)``)
    from their measured coordinates, one row per ground observation (unweighted)."""
    gobs = problem.ground
    frame = _frame(problem) if gobs.frame is None else gobs.frame
    ecef = geodesy.geodetic_to_ecef_near(frame.trig0, _offset(problem, u), ground[gobs.point, 2])
    return jnp.einsum("cij,cj->ci", frame.rotation, ecef - frame.ecef)


def _frame(problem: Problem) -> GroundFrame:
    gobs = problem.ground
    return GroundFrame(
        trig0=geodesy.lonlat_trig(problem.origin[gobs.point]),
        rotation=geodesy.enu_rotation(gobs.lonlath[:, 0], gobs.lonlath[:, 1]),
        ecef=geodesy.geodetic_to_ecef(gobs.lonlath),
    )


def with_frames(problem: Problem) -> Problem:
    """``problem`` with its ground observations' :class:`~._observations.GroundFrame` computed
    (a function of ``origin`` and ``lonlath``: derivatives flow through it), so that a solve's
    iterations do not recompute them: XLA fuses a ``jnp.sin`` into every consumer's loop."""
    frame = _frame(problem)
    return eqx.tree_at(lambda p: p.ground.frame, problem, frame, is_leaf=lambda x: x is None)


def beyond_offset(problem: Problem, u: Float[Array, "n 3"]) -> Bool[Array, ""]:
    """Whether a GCP-observed point lies more than ``geodesy.OFFSET_MAX_RAD`` from its origin
    (there :func:`enu_residuals` is no longer exact to rounding)."""
    return jnp.any(jnp.abs(_offset(problem, u)) > geodesy.OFFSET_MAX_RAD)
