"""Initial values of the generic pushbroom model from scene metadata (000_, section 3.3.1).

Host-side numpy: the orbit circle through the first and last row centres raised by the flying
height, iterated until the viewing rays of the mounting hit them (:func:`initial_geometry`),
plus the line time and focal length where the metadata lack them. Used by
:meth:`jaxgeo.models.GenericPushbroom.from_metadata`.
"""

from __future__ import annotations

import numpy as np

from ..geodesy import GM_EARTH_M3_S2, geodetic_to_ecef
from ..rotations import mounting_rotation, orbit_frame


def _mid_geodetic(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    dlon = (b[0] - a[0] + 180.0) % 360.0 - 180.0
    return np.array([a[0] + dlon / 2.0, (a[1] + b[1]) / 2.0, (a[2] + b[2]) / 2.0])


def _circle(s_f: np.ndarray, s_l: np.ndarray):
    """Great circle about the Earth centre from ``s_f`` to ``s_l`` (both at radius ``R_s``).

    Returns ``(at, theta, r_o)``: positions ``at(frac)`` at fractions of the arc (uniform
    angular motion), the arc angle, and ``R_O``, the orbit frame at the arc's middle.
    """
    r_s = np.linalg.norm(s_f)
    e1 = s_f / r_s
    n = np.cross(s_f, s_l)
    n = n / np.linalg.norm(n)
    e2 = np.cross(n, e1)
    theta = np.arctan2(s_l @ e2, s_l @ e1)

    def at(frac):
        phi = theta * np.asarray(frac, dtype=float)[..., None]
        return r_s * (np.cos(phi) * e1 + np.sin(phi) * e2)

    half = theta / 2.0
    mid = r_s * (np.cos(half) * e1 + np.sin(half) * e2)
    tangent = -np.sin(half) * e1 + np.cos(half) * e2
    return at, theta, np.asarray(orbit_frame(mid, tangent))


def _ray_sphere(point: np.ndarray, direction: np.ndarray, radius: float) -> np.ndarray:
    """Where ``point + mu * direction`` (``mu > 0``, unit direction) meets the sphere ``radius``."""
    pd = point @ direction
    disc = pd * pd - point @ point + radius * radius
    if not disc > 0.0:
        raise ValueError("the viewing ray does not reach the orbit sphere")
    return point + (-pd + np.sqrt(disc)) * direction


def initial_geometry(scene, threshold_m, max_iterations, earth_radius_m) -> dict:
    """Numpy part of :meth:`GenericPushbroom.from_metadata` (section 3.3.1)."""
    name = f"scene {getattr(scene, 'image_id', '?')!r}"
    corners = np.asarray(scene.corners, dtype=float)
    if corners.shape != (4, 3) or not np.all(np.isfinite(corners)):
        raise ValueError(
            f"{name}: corners must be a finite (4, 3) array of (lon_deg, lat_deg, h_m) in the "
            f"order UL, UR, LR, LL, got {corners.tolist()}"
        )
    n_cols, n_rows = int(scene.n_cols), int(scene.n_rows)
    if n_cols < 2 or n_rows < 2:
        raise ValueError(f"{name}: n_cols and n_rows must be >= 2, got {n_cols} x {n_rows}")
    height = float(scene.flying_height_m)
    if not height > 0.0:
        raise ValueError(f"{name}: flying_height_m must be > 0, got {height}")
    alpha = np.deg2rad(float(scene.along_track_angle_deg))
    beta = np.deg2rad(float(scene.across_track_angle_deg or 0.0))
    ecef = lambda g: np.asarray(geodetic_to_ecef(g))
    m_f = ecef(_mid_geodetic(corners[0], corners[1]))
    m_l = ecef(_mid_geodetic(corners[3], corners[2]))
    radius = float(earth_radius_m or 0.5 * (np.linalg.norm(m_f) + np.linalg.norm(m_l)))
    r_s = radius + height
    s_f, s_l = (m * (1.0 + height / radius) for m in (m_f, m_l))
    s_f, s_l = (s * r_s / np.linalg.norm(s) for s in (s_f, s_l))
    view = -np.asarray(mounting_rotation(alpha, beta))[:, 2]  # Z_0 / |Z_0|: towards the ground
    for _ in range(int(max_iterations)):
        _, _, r_o = _circle(s_f, s_l)
        g = r_o @ view
        new_f, new_l = (_ray_sphere(m, -g, r_s) for m in (m_f, m_l))
        move = max(np.linalg.norm(new_f - s_f), np.linalg.norm(new_l - s_l))
        s_f, s_l = new_f, new_l
        if move < threshold_m:
            break
    else:
        raise RuntimeError(
            f"{name}: orbit initialisation did not converge to {threshold_m} m in "
            f"{max_iterations} iterations (last move {move:.3g} m)"
        )
    at, theta, r_o = _circle(s_f, s_l)
    c = ecef(corners)
    if (c[1] - c[0]) @ r_o[:, 1] <= 0.0 or (c[2] - c[3]) @ r_o[:, 1] <= 0.0:
        raise ValueError(
            f"{name}: the corners put x = n_cols - 1 to the right of the flight direction (first "
            "row -> last row); columns must grow to its left (the image seen from above). Check "
            "the corner order UL, UR, LR, LL."
        )
    line_time = scene.line_time_s
    if line_time is None:  # an attitude fixed in the orbit frame sweeps the ground at the orbit's
        # angular rate: the row centres M_F, M_L are as many radians apart as the orbit travels
        ground_angle = np.arccos(
            np.clip(m_f @ m_l / np.linalg.norm(m_f) / np.linalg.norm(m_l), -1, 1)
        )
        line_time = ground_angle / np.sqrt(GM_EARTH_M3_S2 / r_s**3) / (n_rows - 1)
    line_time = float(line_time)
    if not line_time > 0.0:
        raise ValueError(f"{name}: line_time_s must be > 0, got {line_time}")
    if scene.focal_length_mm is not None and scene.pixel_size_um is not None:
        focal_px = float(scene.focal_length_mm) * 1e3 / float(scene.pixel_size_um)
    else:  # coarse: slant range over the ground size of one pixel across track
        swath = 0.5 * (np.linalg.norm(c[1] - c[0]) + np.linalg.norm(c[2] - c[3]))
        slant = 0.5 * (np.linalg.norm(s_f - m_f) + np.linalg.norm(s_l - m_l))
        focal_px = slant * (n_cols - 1) / swath
    lon = corners[0, 0] + (corners[:, 0] - corners[0, 0] + 180.0) % 360.0 - 180.0
    centre = np.array([lon.mean(), corners[:, 1].mean(), corners[:, 2].mean()])
    centre[0] = (centre[0] + 180.0) % 360.0 - 180.0
    return {
        "circle": at,
        "rotation_orbit": r_o,
        "view_angles_rad": np.array([alpha, beta]),
        "focal_px": focal_px,
        "line_time_s": line_time,
        "first_line_time_s": float(scene.first_line_time_s or 0.0),
        "centre_ground": centre,
    }
