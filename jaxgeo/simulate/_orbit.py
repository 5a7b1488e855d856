"""Orbit simulation: circular Kepler orbits and the ephemeris models fitted to them.

Host-side (numpy) construction of :class:`~jaxgeo.models.EphemerisModel` s from physical mission
parameters: a circular (sun-synchronous) orbit placed over a site (:class:`CircularOrbit`), its
yaw-steering attitude (:func:`ground_track_attitude`) and the polynomial fit of both
(:func:`ephemeris_from_orbit`, with :class:`EphemerisSettings`). Positions m, velocities m/s,
times s, angles rad unless ``_deg``.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .. import geodesy
from ..models import EphemerisModel
from ..rotations import angles_from_matrix, orbit_frame
from ._scene import check_finite, check_int, check_positive

J2 = 1.08262668e-3
"""Earth's second zonal harmonic (sun-synchronous inclination)."""
SUN_SYNC_RATE_RAD_S = 2.0 * math.pi / (365.2421897 * 86400.0)
"""Required nodal precession of a sun-synchronous orbit (rad/s)."""


# ---------------------------------------------------------------------- orbits and missions


def sun_synchronous_inclination_deg(altitude_m: float) -> float:
    """Inclination (deg) of a circular sun-synchronous orbit ``altitude_m`` above the equator."""
    a = geodesy.WGS84_A_M + altitude_m
    cos_i = (
        -2.0
        * SUN_SYNC_RATE_RAD_S
        * a**3.5
        / (3.0 * J2 * geodesy.WGS84_A_M**2 * math.sqrt(geodesy.GM_EARTH_M3_S2))
    )
    return math.degrees(math.acos(cos_i))


@dataclasses.dataclass(frozen=True)
class CircularOrbit:
    """Circular Kepler orbit: radius ``WGS84_A + altitude_m``, ascending node ``raan_rad`` and
    argument of latitude ``arg_lat0_rad`` at ``t = 0`` (ECI of the model)."""

    altitude_m: float
    inclination_deg: float
    raan_rad: float
    arg_lat0_rad: float

    @property
    def radius_m(self) -> float:
        return geodesy.WGS84_A_M + self.altitude_m

    @property
    def mean_motion_rad_s(self) -> float:
        return math.sqrt(geodesy.GM_EARTH_M3_S2 / self.radius_m**3)

    def state(self, t_s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """ECI position (m) and velocity (m/s), each ``(n, 3)``, at times ``t_s``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        u = self.arg_lat0_rad + self.mean_motion_rad_s * t
        i, o = math.radians(self.inclination_deg), self.raan_rad
        cu, su, ci, si, co, so = (
            np.cos(u),
            np.sin(u),
            math.cos(i),
            math.sin(i),
            math.cos(o),
            math.sin(o),
        )
        r, v = self.radius_m, self.radius_m * self.mean_motion_rad_s
        pos = r * np.stack([co * cu - so * su * ci, so * cu + co * su * ci, su * si], -1)
        vel = v * np.stack([-co * su - so * cu * ci, -so * su + co * cu * ci, cu * si], -1)
        return pos, vel

    @classmethod
    def over(
        cls,
        lon_deg: float,
        lat_deg: float,
        altitude_m: float,
        inclination_deg: float,
        sidereal_angle_rad: float,
        t_over_s: float = 0.0,
        descending: bool = True,
    ) -> CircularOrbit:
        """The orbit whose radius vector passes through ``(lon, lat, 0)`` at ``t_over_s``."""
        ecef = np.asarray(geodesy.geodetic_to_ecef(jnp.array([lon_deg, lat_deg, 0.0])))
        lat_gc = math.asin(ecef[2] / np.linalg.norm(ecef))
        i = math.radians(inclination_deg)
        ratio = math.sin(lat_gc) / math.sin(i)
        if abs(ratio) > 1.0:
            raise ValueError(
                f"an orbit of inclination {inclination_deg} deg never reaches lat {lat_deg}"
            )
        u = math.pi - math.asin(ratio) if descending else math.asin(ratio)
        theta = sidereal_angle_rad + geodesy.OMEGA_EARTH_RAD_S * t_over_s
        raan = math.radians(lon_deg) + theta - math.atan2(math.sin(u) * math.cos(i), math.cos(u))
        orbit = cls(altitude_m, inclination_deg, raan, 0.0)
        return dataclasses.replace(orbit, arg_lat0_rad=u - orbit.mean_motion_rad_s * t_over_s)


def ground_track_attitude(pos_eci: np.ndarray, vel_eci: np.ndarray) -> np.ndarray:
    """Yaw-steering attitude ``(n, 3)`` (omega, phi, kappa rad): the body x axis follows the
    ground-relative (ECEF) velocity, so tilted cameras sweep the same ground track (the Earth
    rotation compensation of Cartosat-1)."""
    pos, vel = np.asarray(pos_eci, float), np.asarray(vel_eci, float)
    w = np.array([0.0, 0.0, geodesy.OMEGA_EARTH_RAD_S])
    q_io = np.asarray(orbit_frame(pos, vel))
    q_ib = np.asarray(orbit_frame(pos, vel - np.cross(w, pos)))
    return np.asarray(angles_from_matrix(np.swapaxes(q_io, -1, -2) @ q_ib))


def fit_polynomial(tau: np.ndarray, values: np.ndarray, order: int) -> np.ndarray:
    """Least-squares coefficients ``(m, order + 1)`` of ``values (n, m)`` in powers of ``tau``."""
    vander = np.asarray(tau, float)[:, None] ** np.arange(order + 1)
    coeffs, *_ = np.linalg.lstsq(vander, np.asarray(values, float), rcond=None)
    return coeffs.T


@dataclasses.dataclass(frozen=True)
class EphemerisSettings:
    """What an :class:`~jaxgeo.models.EphemerisModel` made from an orbit
    (:func:`ephemeris_from_orbit`) needs besides the orbit and the image's own timing: the
    sidereal angle at ``t = 0`` (rad), the camera (``focal_length_m``, ``pixel_size_m``), the
    image (``line_time_s``, ``n_rows`` x ``n_cols`` px), the polynomial orders of position,
    velocity (default: the position's) and attitude fitted to ``n_samples`` states over the time
    span, and the model's reference height ``h_ref_m``."""

    sidereal_angle_rad: float
    line_time_s: float
    n_rows: int
    n_cols: int
    focal_length_m: float
    pixel_size_m: float
    position_order: int = 3
    velocity_order: int | None = None
    attitude_order: int = 5
    h_ref_m: float = 0.0
    n_samples: int = 201

    def __post_init__(self):
        check_finite(self, "sidereal_angle_rad", "h_ref_m")
        check_positive(self, "line_time_s", "focal_length_m", "pixel_size_m")
        for name, low in (("n_rows", 1), ("n_cols", 1), ("position_order", 0),
                          ("attitude_order", 0)):  # fmt: skip
            check_int(self, name, low)
        if self.velocity_order is not None:
            check_int(self, "velocity_order", 0)
        orders = (self.position_order, self.velocity_order or 0, self.attitude_order)
        check_int(self, "n_samples", max(orders) + 1)


def ephemeris_from_orbit(
    orbit: CircularOrbit,
    t_span_s: tuple[float, float],
    settings: EphemerisSettings,
    *,
    first_line_time_s: float,
    view_angles_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
    attitude_offsets_rad: ArrayLike | None = None,
) -> EphemerisModel:
    """A model from physical mission parameters (``settings``, and the image's
    ``first_line_time_s`` and camera ``view_angles_deg``): the polynomials are fitted to the
    circular orbit and its yaw-steering attitude over ``t_span_s``; ``attitude_offsets_rad``
    ``(3, k)`` adds polynomial pointing deviations (of ``tau``) to the steering law."""
    s = settings
    t0, t1 = (float(v) for v in t_span_s)
    if not t1 > t0:
        raise ValueError(f"empty time span {t_span_s}")
    t_ref, t_scale = 0.5 * (t0 + t1), 0.5 * (t1 - t0)
    t = np.linspace(t0, t1, s.n_samples)
    tau = (t - t_ref) / t_scale
    pos, vel = orbit.state(t)
    att = fit_polynomial(tau, ground_track_attitude(pos, vel), s.attitude_order)
    if attitude_offsets_rad is not None:
        off = np.asarray(attitude_offsets_rad, float)
        att[:, : off.shape[1]] += off[:, : att.shape[1]]
    f = lambda v: jnp.asarray(v, dtype=float)  # noqa: E731
    return EphemerisModel(
        position_coeffs=f(fit_polynomial(tau, pos, s.position_order)),
        velocity_coeffs=f(fit_polynomial(tau, vel, s.velocity_order or s.position_order)),
        attitude_coeffs=f(att),
        view_angles_rad=f(np.radians(view_angles_deg)),
        t_ref_s=f(t_ref),
        t_scale_s=f(t_scale),
        first_line_time_s=f(first_line_time_s),
        line_time_s=f(s.line_time_s),
        sidereal_angle_rad=f(s.sidereal_angle_rad),
        focal_length_m=f(s.focal_length_m),
        pixel_size_m=f(s.pixel_size_m),
        principal_col_px=f(0.5 * (s.n_cols - 1)),
        ccd_offset_m=f(0.0),
        h_ref_m=f(s.h_ref_m),
        n_rows=int(s.n_rows),
        n_cols=int(s.n_cols),
    )
