"""Rotation matrices in pure JAX: elementary, omega/phi/kappa, roll/pitch/yaw, orbit frames.

Angles are radians. All functions broadcast over leading batch axes of their angle inputs and
return ``(..., 3, 3)`` matrices. Rotations are *passive-free*: ``rot_x(a) @ v`` rotates the
vector ``v`` by ``a`` about the x axis (right-handed, counter-clockwise seen from +x).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float


def _stack33(rows):
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def rot_x(angle_rad: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 3 3"]:
    """Rotation by ``angle_rad`` about the x axis."""
    a = jnp.asarray(angle_rad, dtype=float)
    c, s, o, z = jnp.cos(a), jnp.sin(a), jnp.ones_like(a), jnp.zeros_like(a)
    return _stack33([(o, z, z), (z, c, -s), (z, s, c)])


def rot_y(angle_rad: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 3 3"]:
    """Rotation by ``angle_rad`` about the y axis."""
    a = jnp.asarray(angle_rad, dtype=float)
    c, s, o, z = jnp.cos(a), jnp.sin(a), jnp.ones_like(a), jnp.zeros_like(a)
    return _stack33([(c, z, s), (z, o, z), (-s, z, c)])


def rot_z(angle_rad: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 3 3"]:
    """Rotation by ``angle_rad`` about the z axis."""
    a = jnp.asarray(angle_rad, dtype=float)
    c, s, o, z = jnp.cos(a), jnp.sin(a), jnp.ones_like(a), jnp.zeros_like(a)
    return _stack33([(c, -s, z), (s, c, z), (z, z, o)])


def omega_phi_kappa(
    omega_rad: Float[ArrayLike, "*batch"],
    phi_rad: Float[ArrayLike, "*batch"],
    kappa_rad: Float[ArrayLike, "*batch"],
) -> Float[Array, "*batch 3 3"]:
    """Photogrammetric rotation ``R = R_x(omega) R_y(phi) R_z(kappa)`` (image -> object)."""
    return rot_x(omega_rad) @ rot_y(phi_rad) @ rot_z(kappa_rad)


def roll_pitch_yaw(
    roll_rad: Float[ArrayLike, "*batch"],
    pitch_rad: Float[ArrayLike, "*batch"],
    yaw_rad: Float[ArrayLike, "*batch"],
) -> Float[Array, "*batch 3 3"]:
    """Platform attitude ``R_P = R_x(roll) R_y(pitch) R_z(yaw)`` (platform -> orbit frame).

    x is along track, y across track, z towards the Earth-centre-opposite direction as set up
    by :func:`orbit_frame`.
    """
    return rot_x(roll_rad) @ rot_y(pitch_rad) @ rot_z(yaw_rad)


def orbit_frame(
    position_m: Float[ArrayLike, "*batch 3"], velocity_m_s: Float[ArrayLike, "*batch 3"]
) -> Float[Array, "*batch 3 3"]:
    """Orbit (local orbital) frame as columns ``[x_along, y_across, z_radial]`` in the input frame.

    ``z`` points from the Earth centre through the satellite, ``y = z x v / |z x v|`` (across
    track) and ``x = y x z`` (along track, close to the velocity). The returned matrix maps
    orbit-frame vectors into the frame of ``position_m`` (e.g. ECEF or ECI).
    """
    p = jnp.asarray(position_m, dtype=float)
    v = jnp.asarray(velocity_m_s, dtype=float)
    z = p / jnp.linalg.norm(p, axis=-1, keepdims=True)
    y = jnp.cross(z, v)
    y = y / jnp.linalg.norm(y, axis=-1, keepdims=True)
    x = jnp.cross(y, z)
    return jnp.stack([x, y, z], axis=-1)


def angles_from_matrix(r: Float[ArrayLike, "*batch 3 3"]) -> Float[Array, "*batch 3"]:
    """Inverse of :func:`omega_phi_kappa`: ``(..., 3, 3) -> (omega, phi, kappa)`` radians
    (``phi`` in ``[-pi/2, pi/2]``)."""
    r = jnp.asarray(r, dtype=float)
    omega = jnp.arctan2(-r[..., 1, 2], r[..., 2, 2])
    phi = jnp.arcsin(jnp.clip(r[..., 0, 2], -1.0, 1.0))
    kappa = jnp.arctan2(-r[..., 0, 1], r[..., 0, 0])
    return jnp.stack([omega, phi, kappa], axis=-1)


def mounting_rotation(
    along_track_angle_rad: Float[ArrayLike, "*batch"],
    across_track_angle_rad: Float[ArrayLike, "*batch"],
) -> Float[Array, "*batch 3 3"]:
    """Camera -> platform rotation ``R_M = [X_M, Y_M, Z_M]`` of eq. 4 of 000_5aba1cb50921f3c6.txt.

    The paper's ``Z_0 = (tan alpha, -tan beta, -1)`` is the viewing direction in the platform
    frame (x along track, y left, z up): forward for ``alpha > 0``, right for ``beta > 0``.
    Two deliberate departures from the printed equation: the camera z axis is *minus* the
    viewing direction (it points from the ground to the sensor, so ``lambda > 0`` in eq. 3 and
    ``x`` grows towards ``+X_M``, the left of the flight: the image as seen from above, not
    mirrored), and ``X_M = (0, cos beta, -sin beta)``: the printed ``cos alpha`` is a typo, that
    vector is neither unit nor orthogonal to ``Z_0`` unless ``alpha = 0``. ``Y_M = Z_M x X_M``.
    """
    a = jnp.asarray(along_track_angle_rad, dtype=float)
    b = jnp.asarray(across_track_angle_rad, dtype=float)
    a, b = jnp.broadcast_arrays(a, b)
    view = jnp.stack([jnp.tan(a), -jnp.tan(b), -jnp.ones_like(a)], axis=-1)
    z = -view / jnp.linalg.norm(view, axis=-1, keepdims=True)
    x = jnp.stack([jnp.zeros_like(b), jnp.cos(b), -jnp.sin(b)], axis=-1)
    y = jnp.cross(z, x)
    return jnp.stack([x, y, z], axis=-1)
