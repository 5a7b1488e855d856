"""Polynomial-ephemeris rigorous pushbroom model (003_a7d3ea260371d8c5.txt, section 2).

Orbit and attitude are polynomials of the scan time (eq. 1), ``q = q0 + q1 tau + ... + qn tau^n``,
for ``q`` in ``Xp, Yp, Zp, Vx, Vy, Vz`` (ECI metres, m/s) and ``omega, phi, kappa`` (rad), with
the normalised time ``tau = (t - t_ref_s) / t_scale_s`` (the raw seconds of a long strip make a
9th-order power basis singular). Orders are free: the paper uses 3 for position and velocity and
up to 9 for attitude.

Frames, in the order of the rotation chain ``M = Q_GI Q_IO Q_OB Q_BP Q_PC`` (eq. 3), which maps a
CCD (camera) vector to ECEF:

- camera C (= CCD, ``Q_PC = I``): x along track, y along the CCD line (columns grow towards +y,
  i.e. to the left of the flight direction), z up; the boresight is ``-z``.
- payload P -> body B: ``Q_BP = R_y(-alpha) R_x(-beta) R_z(gamma)``, the camera mounting from the
  along-track view angle ``alpha`` (+ forward, Cartosat-1 fore +26 deg, aft -5 deg), the
  across-track angle ``beta`` (+ to the right) and the rotation ``gamma`` of the CCD line.
- body B -> orbit O: ``Q_OB = R_x(omega) R_y(phi) R_z(kappa)`` (roll, pitch, yaw polynomials).
- orbit O -> inertial I: ``Q_IO = [x_along, y_across, z_radial]`` built from the position and
  velocity polynomials (:func:`jaxgeo.rotations.orbit_frame`).
- inertial I -> ECEF G: ``Q_GI = R_z(-theta(t))`` with the sidereal angle
  ``theta(t) = sidereal_angle_rad + OMEGA_EARTH_RAD_S * t`` (GMST at ``t = 0`` plus the Earth's
  rotation, as the ADIF's tabulated sidereal angle; no precession, nutation or polar motion: the
  ECI frame is the true-of-date equator frame at the epoch).

Collinearity (eq. 2): a ground point ``X`` (ECEF) is seen at the time ``t`` where it lies in the
scan plane of the CCD, ``d = M(t)^T (X - Xp(t))``, ``d_x / -d_z = ccd_offset_m / f``, and at the
image column ``x = principal_col_px + (f d_y / -d_z) / pixel_size_m``; the row is
``y = (t - first_line_time_s) / line_time_s`` (integer rows are the centres of the integration).

``project`` solves for ``t`` by Newton's method (a fixed number of steps on the offset from the
scan plane, :func:`scan_time`), differentiated by the implicit function theorem, exact to every
order at convergence; ``localize`` is a direct ray / ellipsoid intersection refined to the exact
ellipsoidal height.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PyTree

from .. import geodesy
from ..rotations import omega_phi_kappa, orbit_frame, rot_x, rot_y, rot_z
from ._base import AbstractSensorModel, all_inexact
from ._newton import newton_root


def polyval(coeffs: Float[Array, "m k"], tau: Float[Array, "*batch"]) -> Float[Array, "*batch m"]:
    """``sum_j coeffs[:, j] tau^j`` (Horner), for every component ``m``."""
    out = jnp.zeros((*jnp.shape(tau), coeffs.shape[0]))
    for j in reversed(range(coeffs.shape[1])):
        out = out * tau[..., None] + coeffs[:, j]
    return out


def _offset(t, args):
    model, ecef = args
    return model._scan_plane_offset(t, ecef)


def scan_time(model: EphemerisModel, ecef: Float[Array, "*batch 3"]) -> Float[Array, "*batch"]:
    """Scan time (s) at which ``model`` images the ECEF points: ``model.newton_steps`` Newton
    steps in ``t`` from the centre line (:func:`~jaxgeo.models.newton_root`), with
    derivatives of every order from the implicit function theorem (``dt = -dg / g_t`` on the
    scan-plane offset ``g``)."""
    t0 = model.centre_time_s()
    flat = ecef.reshape(-1, 3)

    def one(point):
        return newton_root(_offset, t0, (model, point), max_steps=model.newton_steps).value

    return jax.vmap(one)(flat).reshape(ecef.shape[:-1])


def mounting(view_angles_rad: Float[ArrayLike, "3"]) -> Float[Array, "3 3"]:
    """``Q_BP = R_y(-alpha) R_x(-beta) R_z(gamma)`` from ``(alpha, beta, gamma)`` in radians."""
    a = jnp.asarray(view_angles_rad, dtype=float)
    return rot_y(-a[..., 0]) @ rot_x(-a[..., 1]) @ rot_z(a[..., 2])


class EphemerisModel(AbstractSensorModel):
    """Rigorous pushbroom model with polynomial ephemeris and attitude (module docstring).

    Fields (arrays; the adjustment chooses which to free):
        position_coeffs / velocity_coeffs: ``(3, n+1)`` ECI m and m/s, polynomials of ``tau``.
        attitude_coeffs: ``(3, n+1)`` omega, phi, kappa (rad) of body -> orbit frame.
        view_angles_rad: ``(3,)`` camera mounting ``(alpha, beta, gamma)``.
        t_ref_s, t_scale_s: time normalisation ``tau = (t - t_ref_s) / t_scale_s``.
        first_line_time_s, line_time_s: scan time of row 0 and the line period (s).
        sidereal_angle_rad: Earth rotation angle (GMST) at ``t = 0``.
        focal_length_m, pixel_size_m, principal_col_px, ccd_offset_m: interior orientation; the
            CCD line lies ``ccd_offset_m`` ahead of the principal point along track.
        h_ref_m: height of :meth:`reference_ground`.
        n_rows, n_cols: image size (integer arrays: traced, so models of any size share one
            compilation; integer leaves are not adjusted by the usual inexact-array filters).
    Static: ``newton_steps`` of :meth:`project` (6 converge to 1e-9 px from 200 s away).
    """

    position_coeffs: Float[Array, "3 np"]
    velocity_coeffs: Float[Array, "3 nv"]
    attitude_coeffs: Float[Array, "3 na"]
    view_angles_rad: Float[Array, "3"]
    t_ref_s: Float[Array, ""]
    t_scale_s: Float[Array, ""]
    first_line_time_s: Float[Array, ""]
    line_time_s: Float[Array, ""]
    sidereal_angle_rad: Float[Array, ""]
    focal_length_m: Float[Array, ""]
    pixel_size_m: Float[Array, ""]
    principal_col_px: Float[Array, ""]
    ccd_offset_m: Float[Array, ""]
    h_ref_m: Float[Array, ""]
    n_rows: Int[Array, ""] = eqx.field(converter=lambda v: jnp.asarray(v, dtype=int))
    n_cols: Int[Array, ""] = eqx.field(converter=lambda v: jnp.asarray(v, dtype=int))
    newton_steps: int = eqx.field(static=True, default=6)

    def __check_init__(self):
        for name in ("position_coeffs", "velocity_coeffs", "attitude_coeffs"):
            shape = getattr(self, name).shape
            if len(shape) < 2 or shape[-2] != 3 or shape[-1] < 1:
                raise ValueError(
                    f"EphemerisModel.{name} must have shape (3, order + 1), got {shape}"
                )
        if self.view_angles_rad.shape[-1:] != (3,):
            raise ValueError(
                f"view_angles_rad must have shape (3,), got {self.view_angles_rad.shape}"
            )
        try:
            rows, cols = np.asarray(self.n_rows), np.asarray(self.n_cols)
        except jax.errors.TracerArrayConversionError:
            return  # built inside a transformation: nothing concrete to check
        if np.any(rows < 1) or np.any(cols < 1):
            raise ValueError(f"image size must be positive, got {rows} rows x {cols} cols")

    # ---------------------------------------------------------------- time, orbit, attitude

    def row_time(self, row: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        """Scan time (s) of an image row (fractional rows allowed)."""
        return self.first_line_time_s + jnp.asarray(row, dtype=float) * self.line_time_s

    def centre_time_s(self) -> Float[Array, ""]:
        return self.row_time(0.5 * (self.n_rows - 1))

    def _tau(self, t):
        return (jnp.asarray(t, dtype=float) - self.t_ref_s) / self.t_scale_s

    def state_eci(self, t: Float[ArrayLike, "*batch"]) -> tuple[Array, Array]:
        """Position (m) and velocity (m/s) in ECI at scan time ``t``, each ``(..., 3)``."""
        tau = self._tau(t)
        return polyval(self.position_coeffs, tau), polyval(self.velocity_coeffs, tau)

    def attitude(self, t: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 3"]:
        """``(omega, phi, kappa)`` radians at scan time ``t``."""
        return polyval(self.attitude_coeffs, self._tau(t))

    def sidereal_angle(self, t: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        return self.sidereal_angle_rad + geodesy.OMEGA_EARTH_RAD_S * jnp.asarray(t, dtype=float)

    def camera_to_eci(self, t: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 3 3"]:
        """``Q_IO Q_OB Q_BP Q_PC`` at scan time ``t``."""
        pos, vel = self.state_eci(t)
        att = self.attitude(t)
        q_ob = omega_phi_kappa(att[..., 0], att[..., 1], att[..., 2])
        return orbit_frame(pos, vel) @ q_ob @ mounting(self.view_angles_rad)

    def camera_to_ecef(self, t: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 3 3"]:
        """The paper's ``M = Q_GI Q_IO Q_OB Q_BP Q_PC`` (CCD -> ECEF) at scan time ``t``."""
        return rot_z(-self.sidereal_angle(t)) @ self.camera_to_eci(t)

    def _camera_vector(self, t, ecef):
        """Camera-frame vector from the perspective centre to ``ecef`` at time ``t``."""
        pos, _ = self.state_eci(t)
        eci = jnp.einsum("...ji,...j->...i", rot_z(-self.sidereal_angle(t)), ecef)
        return jnp.einsum("...ji,...j->...i", self.camera_to_eci(t), eci - pos)

    def _scan_plane_offset(self, t, ecef):
        """``n . d / (-d_z body)``: zero when the point is in the CCD's scan plane.

        ``n = (f, 0, ccd_offset)`` is the normal of the plane through the perspective centre and
        the CCD line (camera frame). Divided by the body-frame depth, it is close to linear in
        ``t`` for any view angle, so Newton converges from far along the track.
        """
        d = self._camera_vector(t, ecef)
        depth = -jnp.einsum("j,...j->...", mounting(self.view_angles_rad)[2], d)
        return (self.focal_length_m * d[..., 0] + self.ccd_offset_m * d[..., 2]) / (
            jnp.hypot(self.focal_length_m, self.ccd_offset_m) * depth
        )

    # -------------------------------------------------------------------- sensor model API

    def project(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        """Ground ``(lon_deg, lat_deg, h_m)`` -> image ``(x, y)`` px (Newton in scan time)."""
        ground = jnp.asarray(ground, dtype=float)
        if ground.shape[-1:] != (3,):
            raise ValueError(
                f"ground coordinates must have a last axis of size 3, got {ground.shape}"
            )
        ecef = geodesy.geodetic_to_ecef(ground)
        t = scan_time(self, ecef)
        d = self._camera_vector(t, ecef)
        col = self.principal_col_px + self.focal_length_m * d[..., 1] / (-d[..., 2]) / (
            self.pixel_size_m
        )
        row = (t - self.first_line_time_s) / self.line_time_s
        return jnp.stack([col, row], axis=-1)

    def image_ray(self, image: Float[ArrayLike, "*batch 2"]) -> tuple[Array, Array]:
        """Perspective centre (ECEF m) and unit ray direction (ECEF) of image points."""
        image = jnp.asarray(image, dtype=float)
        t = self.row_time(image[..., 1])
        ys = (image[..., 0] - self.principal_col_px) * self.pixel_size_m
        u = jnp.stack(
            [
                jnp.broadcast_to(self.ccd_offset_m, ys.shape),
                ys,
                jnp.broadcast_to(-self.focal_length_m, ys.shape),
            ],
            axis=-1,
        )
        pos, _ = self.state_eci(t)
        q_gi = rot_z(-self.sidereal_angle(t))
        centre = jnp.einsum("...ij,...j->...i", q_gi, pos)
        d = jnp.einsum("...ij,...j->...i", q_gi @ self.camera_to_eci(t), u)
        return centre, d / jnp.linalg.norm(d, axis=-1, keepdims=True)

    def _localize_point(self, image, h, guess):
        """Direct, not the shared Newton on ``project``: the image ray meets the ellipsoid
        inflated by ``h``, then Newton steps along the ray on the exact geodetic height.
        ``guess`` is ignored. A ray that misses the ellipsoid gives NaN."""
        del guess
        centre, d = self.image_ray(image)
        axes = jnp.stack([geodesy.WGS84_A_M + h, geodesy.WGS84_A_M + h, geodesy.WGS84_B_M + h])
        p, q = centre / axes, d / axes
        qa, qb, qc = jnp.sum(q * q, -1), jnp.sum(p * q, -1), jnp.sum(p * p, -1) - 1.0
        disc = qb * qb - qa * qc
        ok = disc >= 0.0
        s = (-qb - jnp.sqrt(jnp.where(ok, disc, 1.0))) / qa

        def refine(_, s):
            geo = geodesy.ecef_to_geodetic(centre + s * d)
            up = geodesy.enu_rotation(geo[0], geo[1])[2, :]
            return s - (geo[2] - h) / jnp.sum(up * d, -1)

        s = jax.lax.fori_loop(0, 3, refine, s)
        geo = geodesy.ecef_to_geodetic(centre + s * d)
        out = jnp.concatenate([geo[:2], h[None]])
        return jnp.where(ok, out, jnp.nan)

    def reference_ground(self) -> Float[Array, "3"]:
        centre = jnp.array([self.principal_col_px, 0.5 * (self.n_rows - 1)])
        return self.localize(centre, self.h_ref_m)

    def adjustable_filter(self) -> PyTree[bool]:
        """Every floating-point leaf (orbit, attitude, mounting, timing, interior orientation):
        give an explicit filter to free fewer."""
        return all_inexact(self)

    def required_gcps(self, dynamic: PyTree) -> None:
        return None

    # ------------------------------------------------------------------------ construction

    def with_rows(self, first_row: float, n_rows: int) -> EphemerisModel:
        """The sub-scene starting at ``first_row`` of this image with ``n_rows`` rows."""
        return dataclasses.replace(self, first_line_time_s=self.row_time(first_row), n_rows=n_rows)

    def to_dict(self) -> dict:
        """Plain JSON-able dict of every field (inverse: :meth:`from_dict`)."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = np.asarray(v).tolist()
        return out

    @classmethod
    def from_dict(cls, d: dict) -> EphemerisModel:
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(d) - set(names))
        if unknown:
            raise KeyError(f"EphemerisModel: unknown field(s) {unknown}")
        ints = ("n_rows", "n_cols", "newton_steps")
        kw = {k: (int(v) if k in ints else jnp.asarray(v, float)) for k, v in d.items()}
        return cls(**kw)


# ---------------------------------------------------------------------------- time


def gmst_rad(utc: str | _dt.datetime) -> float:
    """Greenwich mean sidereal time (rad) of a UTC instant (IAU 1982 expression, UT1 = UTC)."""
    if isinstance(utc, str):
        utc = _dt.datetime.fromisoformat(utc.replace("Z", "+00:00"))
    if utc.tzinfo is None:
        utc = utc.replace(tzinfo=_dt.UTC)
    j2000 = _dt.datetime(2000, 1, 1, 12, tzinfo=_dt.UTC)
    d = (utc - j2000).total_seconds() / 86400.0
    c = d / 36525.0
    deg = 280.46061837 + 360.98564736629 * d + 0.000387933 * c**2 - c**3 / 38710000.0
    return math.radians(deg % 360.0)
