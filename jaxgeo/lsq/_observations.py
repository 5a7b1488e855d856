"""Observation blocks as arrays: image measurements per (group, image slot), ground coordinates.

Built from the user's tables by :func:`jaxgeo.bundle.prepare`; the pieces of a
:class:`~jaxgeo.lsq.Problem`. Image coordinates ``(x, y) = (col, row)`` px, ground
``(lon_deg, lat_deg, h_m)``; weights are ``1 / sigma``.
"""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float, Int


class ImageObs(eqx.Module):
    """Image measurements of image ``slot`` of the blocks of group ``group``.

    ``block`` (m,) block index in the group, ``point`` (m,) ground point index, ``xy`` (m, 2) px,
    ``weight`` (m,) = 1 / sigma_px. ``block_start``: when the observations are sorted by block,
    the (static) first observation of each block and the end, ``(n_blocks + 1,)``: the
    residuals are then evaluated block by block on slices (no per-observation copy of the
    model); empty otherwise.
    """

    block: Int[Array, " m"]
    point: Int[Array, " m"]
    xy: Float[Array, "m 2"]
    weight: Float[Array, " m"]
    group: int = eqx.field(static=True)
    slot: int = eqx.field(static=True)
    block_start: tuple[int, ...] = eqx.field(static=True, default=())


class GroundObs(eqx.Module):
    """Ground-coordinate observations: ``point`` (c,), ``lonlath`` (c, 3), ``weight`` (c, 3) =
    1/sigma per east/north/up axis in metres (0 for an axis without observation)."""

    point: Int[Array, " c"]
    lonlath: Float[Array, "c 3"]
    weight: Float[Array, "c 3"]
    frame: GroundFrame | None = None
    """Precomputed trigonometry of the residuals (:func:`~._ground.with_frames`), or ``None``."""


class GroundFrame(eqx.Module):
    """What the ground residuals of :mod:`~._ground` need that does not change during a solve:
    ``trig0`` (c, 4) ``(sin lon, cos lon, sin lat, cos lat)`` of each observed point's origin,
    ``rotation`` (c, 3, 3) the ENU rotation at each measured ``lonlath``, ``ecef`` (c, 3) its
    ECEF position (m)."""

    trig0: Float[Array, "c 4"]
    rotation: Float[Array, "c 3 3"]
    ecef: Float[Array, "c 3"]
