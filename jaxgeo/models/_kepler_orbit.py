"""Two-body orbit propagation and frames for the Kepler along-track model, in pure JAX.

- :func:`propagate`: exact two-body motion by the universal variable (Lagrange f and g), the
  root of Kepler's equation differentiated implicitly;
- :func:`taylor_coefficients` / :func:`taylor_state`: the Taylor series of the same motion
  about one state (the Taylor-series method), a loop-free polynomial per image point;
- :func:`propagate_taylor2`: the paper's second-order series (002_0f5a34c3ba5aae9c.txt);
- the inertial frame equal to ECEF at the epoch (:func:`ecef_to_inertial`), the camera
  mounting from the view angles and elementary rotations applied to vectors;
- initial values from scene metadata: a circular orbit whose boresight hits each scene
  (section 3.3.1 of 000_5aba1cb50921f3c6.txt), made consistent across a fore/aft pair.

Positions in metres, velocities in m/s, times in seconds, angles in radians unless ``_deg``.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import geodesy
from ..rotations import orbit_frame, rot_x, rot_y, rot_z
from ._metadata import SceneMetadata
from ._newton import newton_root

GM_M3_S2 = geodesy.GM_EARTH_M3_S2
OMEGA_RAD_S = geodesy.OMEGA_EARTH_RAD_S
PROPAGATORS = ("universal", "taylor2")
_STUMPFF_TERMS = 20  # C(z), S(z) exact to float64 for |z| < 40: arcs up to one period
_KEPLER_ITERATIONS = 10
_TAYLOR_ORDER = 9  # orbit series: < 1e-7 m within 150 s of the expansion point (LEO, e < 0.01)


# --- two-body propagation -----------------------------------------------------------------


def _stumpff(z):
    """Stumpff ``C(z) = sum (-z)^k / (2k+2)!``, ``S(z) = sum (-z)^k / (2k+3)!`` (Horner):
    smooth through ``z = 0`` and differentiable to any order."""
    c = s = jnp.zeros_like(z)
    for k in reversed(range(_STUMPFF_TERMS)):
        c = 1.0 / math.factorial(2 * k + 2) - z * c
        s = 1.0 / math.factorial(2 * k + 3) - z * s
    return c, s


def _kepler_equation(chi, args):
    """Universal Kepler equation (Curtis eq. 3.49) as ``F(chi) - sqrt(mu) dt``."""
    r0n, vr0_mu, alpha, mu_dt = args
    z = alpha * chi**2
    c, s = _stumpff(z)
    value = r0n * vr0_mu * chi**2 * c + (1.0 - alpha * r0n) * chi**3 * s + r0n * chi
    return value - mu_dt


def _universal_anomaly(r0n, vr0_mu, alpha, mu_dt):
    """Root ``chi`` of the universal Kepler equation, ``_KEPLER_ITERATIONS`` Newton steps from
    ``alpha sqrt(mu) dt`` (:func:`~jaxgeo.models.newton_root`: implicit derivatives of
    every order)."""
    args = (r0n, vr0_mu, alpha, mu_dt)
    return newton_root(_kepler_equation, alpha * mu_dt, args, max_steps=_KEPLER_ITERATIONS).value


def propagate(
    position_m: Float[ArrayLike, "3"],
    velocity_m_s: Float[ArrayLike, "3"],
    dt_s: Float[ArrayLike, ""],
    gm: float = GM_M3_S2,
) -> tuple[Float[Array, "3"], Float[Array, "3"]]:
    """Two-body state after ``dt_s`` seconds by the universal variable (Lagrange f and g).

    Inertial position (m) and velocity (m/s) in, the same out; exact to float64 rounding for
    ``|dt|`` up to about one orbital period (tests compare with numerical integration).
    """
    r0, v0 = jnp.asarray(position_m, dtype=float), jnp.asarray(velocity_m_s, dtype=float)
    dt = jnp.asarray(dt_s, dtype=float)
    sqrt_mu = jnp.sqrt(gm)
    r0n = jnp.linalg.norm(r0)
    alpha = 2.0 / r0n - jnp.dot(v0, v0) / gm  # 1 / semi-major axis
    chi = _universal_anomaly(r0n, jnp.dot(r0, v0) / r0n / sqrt_mu, alpha, sqrt_mu * dt)
    z = alpha * chi**2
    c, s = _stumpff(z)
    r = (1.0 - chi**2 / r0n * c) * r0 + (dt - chi**3 * s / sqrt_mu) * v0
    rn = jnp.linalg.norm(r)
    fdot = sqrt_mu / (rn * r0n) * (z * s - 1.0) * chi
    return r, fdot * r0 + (1.0 - chi**2 / rn * c) * v0


def propagate_taylor2(position_m, velocity_m_s, dt_s, gm: float = GM_M3_S2):
    """The paper's series ``X_c = X0 + u tau - GM X0 tau^2 / (2 |X0|^3)`` and its derivative
    (002_ prints ``|X0|^2``; ``|X0|^3`` is the two-body acceleration)."""
    return taylor_state(_taylor2_coefficients(position_m, velocity_m_s, gm), dt_s)


def _taylor2_coefficients(position_m, velocity_m_s, gm=GM_M3_S2):
    r0, v0 = jnp.asarray(position_m, dtype=float), jnp.asarray(velocity_m_s, dtype=float)
    return jnp.stack([r0, v0, -0.5 * gm * r0 / jnp.linalg.norm(r0) ** 3])


def taylor_coefficients(
    position_m: Float[ArrayLike, "3"],
    velocity_m_s: Float[ArrayLike, "3"],
    order: int = _TAYLOR_ORDER,
    gm: float = GM_M3_S2,
) -> Float[Array, "order_plus_1 3"]:
    """Taylor coefficients ``r_k`` of the two-body orbit, ``r(dt) = sum_k r_k dt^k``.

    The Taylor-series method for ``r'' = -gm r w``, ``w = s^(-3/2)``, ``s = r.r``: Cauchy
    products for ``s`` and the acceleration, the power rule ``k s0 w_k = sum_j (j/2 - k)`` ...
    ``s_j w_(k-j)`` (``alpha + 1 = -1/2``) for ``w``. Loop-free and differentiable.
    """
    r = jnp.zeros((order + 1, 3))
    r = r.at[0].set(jnp.asarray(position_m, dtype=float))
    r = r.at[1].set(jnp.asarray(velocity_m_s, dtype=float))
    s = w = jnp.zeros(0)
    # each Cauchy product as one whole-array expression over the terms so far (a few operations
    # per order instead of one per term: a smaller program wherever the orbit is traced)
    for k in range(order - 1):
        s = jnp.append(s, jnp.sum(r[: k + 1] * r[k::-1]))
        if k == 0:
            w_k = s[0] ** -1.5
        else:
            j = np.arange(1, k + 1)
            w_k = jnp.sum((-0.5 * j - k) * s[1 : k + 1] * w[::-1]) / (k * s[0])
        w = jnp.append(w, w_k)
        r = r.at[k + 2].set(-gm * (w[::-1] @ r[: k + 1]) / ((k + 1) * (k + 2)))
    return r


def taylor_state(
    coefficients: Float[Array, "n 3"], dt_s: Float[ArrayLike, ""]
) -> tuple[Float[Array, "3"], Float[Array, "3"]]:
    """Position and velocity of the series ``sum_k r_k dt^k`` at ``dt_s``."""
    dt = jnp.asarray(dt_s, dtype=float)
    n = coefficients.shape[0]
    powers = [jnp.ones_like(dt)]
    for _ in range(n - 1):
        powers.append(powers[-1] * dt)
    powers = jnp.stack(powers)
    r = powers @ coefficients
    v = (np.arange(1, n, dtype=float) * powers[:-1]) @ coefficients[1:]
    return r, v


def _spin(vector, angle):
    """``R_z(angle) @ vector`` over the last axis."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    x, y, z = vector[..., 0], vector[..., 1], vector[..., 2]
    return jnp.stack([c * x - s * y, s * x + c * y, z], axis=-1)


def ecef_to_inertial(vector: Float[ArrayLike, "*batch 3"], tau_s) -> Float[Array, "*batch 3"]:
    """ECEF vector at ``tau_s`` -> the inertial frame that equals ECEF at ``tau = 0``."""
    return _spin(jnp.asarray(vector, dtype=float), OMEGA_RAD_S * jnp.asarray(tau_s))


def inertial_to_ecef(vector: Float[ArrayLike, "*batch 3"], tau_s) -> Float[Array, "*batch 3"]:
    """Inverse of :func:`ecef_to_inertial`."""
    return _spin(jnp.asarray(vector, dtype=float), -OMEGA_RAD_S * jnp.asarray(tau_s))


def kepler_mounting(
    along_track_angle_deg: float, across_track_angle_deg: float
) -> Float[Array, "3 3"]:
    """Camera-to-platform rotation ``R_M = R_y(-alpha) R_x(-beta)``."""
    a, b = np.deg2rad(along_track_angle_deg), np.deg2rad(across_track_angle_deg)
    return rot_y(-a) @ rot_x(-b)


def _rotate(vector, axis, angle, transpose=False):
    """Elementary rotation ``R_axis(angle)`` (or its transpose) applied to a 3-vector.

    ``v + (c - 1) m v + s K v`` with constant ``m`` (ones on the rotated plane) and ``K`` (the
    plane's quarter turn): a few whole-vector operations, not one per component (the Kepler
    model applies three per ray, and a solve traces dozens of rays)."""
    c, s = jnp.cos(angle), (-1.0 if transpose else 1.0) * jnp.sin(angle)
    return vector + (c - 1.0) * (_PLANE[axis] * vector) + s * (_QUARTER[axis] @ vector)


def _plane_constants():
    plane, quarter = np.zeros((3, 3)), np.zeros((3, 3, 3))
    for axis, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):
        plane[axis, [i, j]] = 1.0
        quarter[axis, i, j], quarter[axis, j, i] = -1.0, 1.0
    return plane, quarter


_PLANE, _QUARTER = _plane_constants()


# --- initial values from metadata (numpy, run once) -------------------------------------------

_propagate_jit = jax.jit(propagate)


def _rot_z_host(angle) -> np.ndarray:
    return np.asarray(rot_z(angle))


def _orbit_frame_host(position, velocity) -> np.ndarray:
    return np.asarray(orbit_frame(position, velocity))


def _ground_track(scene: SceneMetadata) -> tuple[np.ndarray, np.ndarray]:
    """ECEF scene centre and unit direction of increasing rows (the ground track)."""
    corners = np.asarray(geodesy.geodetic_to_ecef(scene.corners))
    first, last = corners[[0, 1]].mean(axis=0), corners[[3, 2]].mean(axis=0)
    track = last - first
    return corners.mean(axis=0), track / np.linalg.norm(track)


def _yaw(x_axis, z_axis, direction) -> float:
    """Angle (rad) about ``z_axis`` from ``x_axis`` to the horizontal part of ``direction``."""
    d = direction - np.dot(direction, z_axis) * z_axis
    return float(np.arctan2(np.dot(np.cross(x_axis, d), z_axis), np.dot(x_axis, d)))


def _circular_state_over(scene, cam, delta_m, iterations):
    """Position and inertial velocity (ECEF axes, at the centre time) of a circular orbit of
    radius ``|centre| + flying height + delta_m`` whose yaw-steered boresight hits the centre
    (the iteration of 3.3.1 in 000_)."""
    centre, track = _ground_track(scene)
    radius = np.linalg.norm(centre) + scene.flying_height_m + delta_m
    speed = np.sqrt(GM_M3_S2 / radius)
    mount = np.asarray(kepler_mounting(cam.along_track_angle_deg, cam.across_track_angle_deg))
    omega = np.array([0.0, 0.0, OMEGA_RAD_S])
    sat = centre * radius / np.linalg.norm(centre)
    for _ in range(iterations):
        up = sat / np.linalg.norm(sat)
        t = track - np.dot(track, up) * up
        t = t / np.linalg.norm(t)
        w = np.cross(omega, sat)  # Earth-fixed velocity at the satellite: v_inertial = s t + w
        tw = np.dot(t, w)
        vel = (-tw + np.sqrt(tw**2 - np.dot(w, w) + speed**2)) * t + w
        frame = _orbit_frame_host(sat, vel)
        kappa = _yaw(frame[:, 0], frame[:, 2], t)
        look = frame @ _rot_z_host(kappa) @ mount @ np.array([0.0, 0.0, -1.0])
        cb = np.dot(centre, look)
        rho = cb + np.sqrt(cb**2 - np.dot(centre, centre) + radius**2)
        sat = centre - rho * look
    return sat, vel


def _epoch_state(scene, cam, delta_m, iterations):
    """The scene's circular state carried back to the sequence epoch (inertial frame)."""
    pos, vel = _circular_state_over(scene, cam, delta_m, iterations)
    rot = _rot_z_host(OMEGA_RAD_S * cam.centre_time_s)
    pos, vel = _propagate_jit(rot @ pos, rot @ vel, -cam.centre_time_s)
    return np.asarray(pos), np.asarray(vel)


def _consistent_height_offset(pairs, iterations, tol_m=0.01) -> float:
    """Common correction (m) of the metadata flying heights that makes the first and the last
    scene agree on the along-track position of the epoch state.

    A nominal height that is off (Cartosat-1 metadata say 618 or 638 km) moves the oblique
    scenes' orbit points by ``dH tan(alpha)`` and splits a fore/aft pair by kilometres; their
    time interval fixes it. Scenes less than 1 s apart, or no root within half the flying
    height, keep the metadata height.
    """
    (s0, c0), (s1, c1) = pairs[0], pairs[-1]
    if len(pairs) < 2 or abs(c1.centre_time_s - c0.centre_time_s) < 1.0:
        return 0.0

    def mismatch(delta):
        (p0, v0), (p1, _) = (_epoch_state(s, c, delta, iterations) for s, c in ((s0, c0), (s1, c1)))
        return float(np.dot(p1 - p0, v0 / np.linalg.norm(v0)))

    d0, d1 = 0.0, 1000.0
    f0, f1 = mismatch(d0), mismatch(d1)
    for _ in range(8):
        if f1 == f0 or abs(f1) < tol_m:
            break
        d0, d1, f0 = d1, d1 - f1 * (d1 - d0) / (f1 - f0), f1
        f1 = mismatch(d1)
    limit = 0.5 * min(s0.flying_height_m, s1.flying_height_m)
    return d1 if abs(f1) < 1.0 and abs(d1) < limit else 0.0


def _yaw_along_track(scene, cam, pos0, vel0) -> float:
    """kappa that turns the orbit frame's x axis onto the ground track at the centre time."""
    tau = cam.centre_time_s
    pos, vel = (np.asarray(v) for v in _propagate_jit(pos0, vel0, tau))
    _, track = _ground_track(scene)
    frame = _orbit_frame_host(pos, vel)
    return _yaw(frame[:, 0], frame[:, 2], _rot_z_host(OMEGA_RAD_S * tau) @ track)
