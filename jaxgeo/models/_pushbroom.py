"""Generic spline pushbroom model (Barista; 000_5aba1cb50921f3c6.txt section 3.3, eq. 3-4).

    p_F - c_F + dx = lambda R_M^T {R_P^T(t) R_O^T [P_ECS - S(t)] - C_M}          (eq. 3)

- ``P_ECS``: ground point in ECEF metres; ``S(t)``: satellite position, a :class:`Spline` of
  ECEF metres; ``R_P(t) = roll_pitch_yaw(roll(t), pitch(t), yaw(t))`` (platform -> orbit frame),
  the angles a :class:`Spline` of radians; ``R_O``: time-constant orbit -> ECEF rotation, the
  ``orbit_frame`` (columns along-track, across-track = left of the flight, radial up) of the
  orbit at the scene centre, fixed when the model is initialised.
- ``R_M``: camera -> platform, eq. 4 from the along-track angle ``alpha`` (+ = forward) and the
  across-track angle ``beta`` (+ = looking right of the flight): see :func:`mounting_rotation`.
- ``p_F = (x_F, 0, 0)`` with ``x_F`` the image column ``x``; ``c_F = (x_F0, y_F0, F)``: principal
  point and focal length in pixels (``F = focal length / pixel size``); ``C_M`` the camera
  offset in the platform (m); ``dx = 0`` (compose :class:`~jaxgeo.models.Biased` for
  image-space corrections).
- Time: ``t = first_line_time_s + y * line_time_s`` seconds after the metadata's sequence
  epoch; with the default ``first_line_time_s = 0`` row 0 is ``t = 0``.

Dividing the first two components of eq. 3 by the third gives the focal-plane coordinates
``x_F(t)`` and ``y_F(t)``. A ground point's row is the time at which it lies in the scan plane,
``y_F(t) = 0``: :meth:`GenericPushbroom.project` finds it by Newton's method. Localisation is
direct: the ray of ``(x, y)`` intersected with the surface at height ``h``. Both roots carry
implicit-function derivatives (a custom JVP), so they differentiate to any order.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PyTree

from ..geodesy import (
    WGS84_A_M,
    WGS84_B_M,
    ecef_to_geodetic,
    geodetic_to_ecef,
)
from ..rotations import mounting_rotation, roll_pitch_yaw
from ._base import AbstractSensorModel
from ._metadata import SceneMetadata
from ._newton import newton_root
from ._pushbroom_init import initial_geometry
from ._spline import Spline, SplineObservations

__all__ = ["GenericPushbroom", "mounting_rotation"]


LOCALIZE_NEWTON_STEPS = 3
"""Newton steps on ``(lon, lat)`` in :meth:`GenericPushbroom.localize`: the start, on the
ellipsoid with both semi-axes raised by ``h``, is right to first order in ``h`` (cm at 4 km)."""


def _f64(x) -> Array:
    return jnp.asarray(x, dtype=float)


def _rotate_vector(v, angle, axis: int):
    """``rot_<axis>(angle) @ v`` for vectors ``(..., 3)`` without building the matrix."""
    i, j = ((1, 2), (2, 0), (0, 1))[axis]
    c, s = jnp.cos(angle), jnp.sin(angle)
    out = [v[..., 0], v[..., 1], v[..., 2]]
    out[i], out[j] = c * v[..., i] - s * v[..., j], s * v[..., i] + c * v[..., j]
    return jnp.stack(out, axis=-1)


def _scan_offset(t, args):
    """``y_F`` (px) of the ECEF point ``args[1]`` at time ``t``: zero in the scan plane."""
    model, ecef, r_m = args
    return model._focal_plane(ecef, t, r_m)[1]


def _ray_offset(lonlat, args):
    """Offsets (m) across the ray ``(origin, e)`` of the point ``(lon, lat, h)``: zero on it."""
    origin, across, h = args
    return across @ (geodetic_to_ecef(jnp.concatenate([lonlat, h[None]])) - origin)


class GenericPushbroom(AbstractSensorModel):
    """The generic pushbroom model of eq. 3 with spline orbit and attitude (see module doc).

    Adjustable parameters are the spline control points ``orbit.coeffs`` (ECEF m) and
    ``attitude.coeffs`` (roll, pitch, yaw rad): :meth:`adjustable_filter` selects them for
    ``eqx.partition``. Soft constraints (section 3.3.2) and direct orbit/attitude observations
    come out of :meth:`prior_residuals`; a ``None`` sigma (or observations) switches one off.
    Defaults: 5 constraint times, 10 m off the orbit plane, 10 m/s radial velocity (a
    near-circular orbit: e = 0.001 gives ~7.5 m/s). ``newton_steps``: Newton steps of
    :meth:`project`.
    """

    orbit: Spline
    attitude: Spline
    rotation_orbit: Float[Array, "3 3"] = eqx.field(converter=_f64)
    view_angles_rad: Float[Array, "2"] = eqx.field(converter=_f64)
    principal_point_px: Float[Array, "2"] = eqx.field(converter=_f64)
    focal_px: Float[Array, ""] = eqx.field(converter=_f64)
    line_time_s: Float[Array, ""] = eqx.field(converter=_f64)
    centre_ground: Float[Array, "3"] = eqx.field(converter=_f64)
    n_cols: int = eqx.field(static=True)
    n_rows: int = eqx.field(static=True)
    first_line_time_s: Float[Array, ""] = eqx.field(default=0.0, converter=_f64)
    camera_offset_m: Float[Array, "3"] = eqx.field(default=(0.0, 0.0, 0.0), converter=_f64)
    orbit_observations: SplineObservations | None = None
    attitude_observations: SplineObservations | None = None
    n_constraint_samples: int = eqx.field(default=5, static=True)
    sigma_plane_m: float | None = eqx.field(default=10.0, static=True)
    sigma_radial_velocity_m_s: float | None = eqx.field(default=10.0, static=True)
    newton_steps: int = eqx.field(default=6, static=True)

    def __check_init__(self):
        for name, shape in (
            ("rotation_orbit", (3, 3)),
            ("view_angles_rad", (2,)),
            ("principal_point_px", (2,)),
            ("focal_px", ()),
            ("line_time_s", ()),
            ("centre_ground", (3,)),
            ("first_line_time_s", ()),
            ("camera_offset_m", (3,)),
        ):
            if getattr(self, name).shape != shape:
                raise ValueError(f"GenericPushbroom.{name} must have shape {shape}")
        if self.orbit.dim != 3 or self.attitude.dim != 3:
            raise ValueError("the orbit and attitude splines must both have dim 3")
        if self.newton_steps < 2:
            raise ValueError(f"newton_steps must be >= 2, got {self.newton_steps}")
        if self.n_cols < 2 or self.n_rows < 2:
            raise ValueError(
                f"image size must be at least 2 x 2, got {self.n_cols} x {self.n_rows}"
            )

    # -- geometry -----------------------------------------------------------------------------

    def time_of_row(self, row: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        """Image row (line) ``y`` -> time ``t`` in seconds after the epoch."""
        return self.first_line_time_s + _f64(row) * self.line_time_s

    def row_of_time(self, t_s: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        """Time ``t`` (s after the epoch) -> image row ``y``."""
        return (_f64(t_s) - self.first_line_time_s) / self.line_time_s

    def mounting_rotation(self) -> Float[Array, "3 3"]:
        """``R_M`` (camera -> platform) of eq. 4, see :func:`mounting_rotation`."""
        return mounting_rotation(self.view_angles_rad[0], self.view_angles_rad[1])

    def platform_rotation(self, t_s: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 3 3"]:
        """``R_P(t)`` (platform -> orbit frame) from the roll/pitch/yaw splines."""
        rpy = self.attitude(t_s)
        return roll_pitch_yaw(rpy[..., 0], rpy[..., 1], rpy[..., 2])

    def camera_to_ecef(self, t_s: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 3 3"]:
        """``R_O R_P(t) R_M``: camera axes in ECEF at time ``t``."""
        return self.rotation_orbit @ self.platform_rotation(t_s) @ self.mounting_rotation()

    def focal_plane(
        self, ecef: Float[ArrayLike, "*batch 3"], t_s: Float[ArrayLike, "*batch"]
    ) -> Float[Array, "*batch 2"]:
        """``(x_F, y_F)`` px of an ECEF point seen at time ``t``: eq. 3 with ``lambda`` removed."""
        return self._focal_plane(_f64(ecef), _f64(t_s), self.mounting_rotation())

    def _focal_plane(self, ecef, t_s, r_m):
        # u = R_M^T {R_P^T(t) R_O^T [P - S(t)] - C_M}, with R_P^T = R_z(-yaw) R_y(-pitch) R_x(-roll)
        # applied to the vector one axis at a time
        w = (ecef - self.orbit(t_s)) @ self.rotation_orbit
        rpy = self.attitude(t_s)
        for axis, k in ((0, 0), (1, 1), (2, 2)):
            w = _rotate_vector(w, -rpy[..., k], axis)
        u = (w - self.camera_offset_m) @ r_m
        f = self.focal_px
        x_f = self.principal_point_px[0] - f * u[..., 0] / u[..., 2]
        y_f = self.principal_point_px[1] - f * u[..., 1] / u[..., 2]
        return jnp.stack([x_f, y_f], axis=-1)

    # -- sensor model -------------------------------------------------------------------------

    def _project_one(self, ecef):
        t_centre = self.time_of_row(0.5 * (self.n_rows - 1))
        r_m = self.mounting_rotation()
        t = newton_root(
            _scan_offset, t_centre, (self, ecef, r_m), max_steps=self.newton_steps
        ).value
        return jnp.stack([self._focal_plane(ecef, t, r_m)[0], self.row_of_time(t)])

    def project(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        """Ground ``(lon_deg, lat_deg, h_m)`` -> image ``(x, y)`` px.

        The row is the time at which the point lies in the scan plane (``y_F(t) = 0``), found by
        ``newton_steps`` Newton steps from the scene centre's time (four already reach 1e-9 px
        for points two scene lengths outside the image); then ``x = x_F(t)``. Derivatives of
        every order are those of the implicit function (exact at the converged root).
        """
        ground = _f64(ground)
        if ground.shape[-1:] != (3,):
            raise ValueError(
                f"ground coordinates must have a last axis of size 3, got {ground.shape}"
            )
        ecef = geodetic_to_ecef(ground).reshape(-1, 3)
        out = jax.vmap(self._project_one)(ecef)
        return out.reshape(*ground.shape[:-1], 2)

    def _localize_point(self, image, h, guess):
        """Direct, not the shared Newton on ``project``: the ray of the pixel at ``t(y)`` (no
        search over time) meets the surface at height ``h`` where a few Newton steps on
        ``(lon, lat)`` put ``(lon, lat, h)`` on the ray, from its intersection with the
        ellipsoid raised by ``h``; implicit derivatives. ``guess`` is ignored. A ray that
        misses the Earth, or a NaN input, gives NaN for that point."""
        del guess
        t = self.time_of_row(image[1])
        origin = (
            self.orbit(t) + self.rotation_orbit @ self.platform_rotation(t) @ self.camera_offset_m
        )
        v = jnp.stack(
            [image[0] - self.principal_point_px[0], -self.principal_point_px[1], -self.focal_px]
        )
        rot = self.camera_to_ecef(t)
        d = rot @ v
        d = d / jnp.linalg.norm(d)
        e1 = rot[:, 0] - (rot[:, 0] @ d) * d  # two unit vectors across the ray
        e1 = e1 / jnp.linalg.norm(e1)
        across = jnp.stack([e1, jnp.cross(d, e1)])
        # start: the ellipsoid with both semi-axes raised by h, right to first order in h
        scale = jnp.stack([WGS84_A_M + h, WGS84_A_M + h, WGS84_B_M + h])
        o_s, d_s = origin / scale, d / scale
        qa, qb, qc = d_s @ d_s, 2.0 * (o_s @ d_s), o_s @ o_s - 1.0
        disc = qb * qb - 4.0 * qa * qc
        hit = disc > 0.0
        # double-where: a ray that misses gives NaN without poisoning gradients elsewhere
        mu0 = (-qb - jnp.sqrt(jnp.where(hit, disc, 1.0))) / (2.0 * qa)
        mu0 = jnp.where(hit, mu0, jnp.nan)
        start = jax.lax.stop_gradient(ecef_to_geodetic(origin + mu0 * d, iterations=1)[:2])
        lonlat = newton_root(
            _ray_offset, start, (origin, across, h), max_steps=LOCALIZE_NEWTON_STEPS
        ).value
        return jnp.concatenate([lonlat, h[None]])

    def reference_ground(self) -> Float[Array, "3"]:
        return self.centre_ground

    # -- soft constraints and direct observations (section 3.3.2) ----------------------------

    def constraint_times(self) -> Float[Array, " k"]:
        """The ``n_constraint_samples`` times of the soft constraints: centres of equal parts."""
        k = self.n_constraint_samples
        t0, t1 = self.orbit.t_start_s, self.orbit.t_end_s
        return t0 + (jnp.arange(k) + 0.5) / k * (t1 - t0)

    def prior_residuals(self) -> Float[Array, " n"]:
        """Weighted residuals of the soft orbit constraints and direct observations.

        - plane (``sigma_plane_m``): ``n . S(t_i) / sigma``, the distance of the orbit from the
          plane through the Earth centre and the orbit's end points ``S(t_start)``,
          ``S(t_end)`` (normal ``n = S(t_start) x S(t_end) / |...|``, derived, not adjusted);
        - circularity (``sigma_radial_velocity_m_s``): ``S . dS/dt / |S| / sigma``, the radial
          velocity (m/s), zero when position and tangent are perpendicular;
        - ``orbit_observations`` / ``attitude_observations``: ``(spline(t) - obs) / sigma``.

        A ``None`` sigma, ``n_constraint_samples = 0`` or absent observations switch a part off.
        """
        parts = []
        if self.n_constraint_samples > 0:
            t = self.constraint_times()
            s = self.orbit(t)
            if self.sigma_plane_m is not None:
                n = jnp.cross(self.orbit(self.orbit.t_start_s), self.orbit(self.orbit.t_end_s))
                n = n / jnp.linalg.norm(n)
                parts.append(s @ n / self.sigma_plane_m)
            if self.sigma_radial_velocity_m_s is not None:
                v = self.orbit.derivative(t)
                radial = jnp.sum(s * v, axis=-1) / jnp.linalg.norm(s, axis=-1)
                parts.append(radial / self.sigma_radial_velocity_m_s)
        if self.orbit_observations is not None:
            parts.append(self.orbit_observations.residuals(self.orbit))
        if self.attitude_observations is not None:
            parts.append(self.attitude_observations.residuals(self.attitude))
        return jnp.concatenate(parts) if parts else jnp.zeros((0,))

    def adjustable_filter(self, orbit: bool = True, attitude: bool = True) -> PyTree[bool]:
        """Filter spec for ``eqx.partition``: True on the orbit and/or attitude control points."""
        spec = jax.tree.map(lambda _: False, self)
        return eqx.tree_at(lambda m: (m.orbit.coeffs, m.attitude.coeffs), spec, (orbit, attitude))

    def required_gcps(self, dynamic: PyTree) -> None:
        """None: the soft orbit constraints and tie points carry the adjustment."""
        return None

    # -- initialisation (section 3.3.1) -------------------------------------------------------

    @classmethod
    def from_metadata(
        cls,
        scene: SceneMetadata,
        degree: int = 2,
        n_segments: int = 1,
        *,
        threshold_m: float = 0.01,
        max_iterations: int = 100,
        earth_radius_m: float | None = None,
        **options,
    ) -> GenericPushbroom:
        """Approximate model from corners, flying height, focal length, pixel size, view angles.

        Section 3.3.1: ``M_F``, ``M_L`` are the centres of the first and last rows (geodetic
        mid-points of the corners); ``S_j^0 = M_j (1 + H / R)``, ``R`` the scene's geocentric
        radius unless ``earth_radius_m`` is given; the orbit is the circle of radius
        ``R_s = R + H`` about the Earth centre through ``S_F``, ``S_L``; ``R_O^i`` its orbit frame
        at the scene centre. Iteration: ``g^i = R_O^i Z_M`` (viewing direction), ``S_j`` moves
        to where the line through ``M_j`` along ``g^i`` meets the sphere ``R_s``, until neither
        end point moves ``threshold_m`` or more. The orbit spline then follows that circle with
        uniform angular motion from ``S_F`` (row 0) to ``S_L`` (last row); attitude zero.

        A missing ``line_time_s`` is derived from the number of rows and the circular orbit's
        angular rate ``sqrt(GM / R_s^3)`` over the geocentric angle ``M_F M_L`` (the ground
        swept by a camera fixed in the orbit frame); a missing focal length or pixel size
        is estimated from the slant range and the swath (``F = range (n_cols - 1) / swath``).
        ``options`` go to the constructor (``n_constraint_samples``, ``sigma_plane_m``,
        ``sigma_radial_velocity_m_s``, ``orbit_observations``, ``attitude_observations``,
        ``newton_steps``, ``camera_offset_m``).
        """
        geo = initial_geometry(scene, threshold_m, max_iterations, earth_radius_m)
        t_f = geo["first_line_time_s"]
        t_l = t_f + (scene.n_rows - 1) * geo["line_time_s"]
        n_fit = 4 * (int(n_segments) + int(degree)) + 1
        times = np.linspace(t_f, t_l, n_fit)
        positions = geo["circle"]((times - t_f) / (t_l - t_f))
        orbit = Spline.fit(times, positions, t_f, t_l, degree, n_segments)
        attitude = Spline.constant(np.zeros(3), t_f, t_l, degree, n_segments)
        return cls(
            orbit=orbit,
            attitude=attitude,
            rotation_orbit=geo["rotation_orbit"],
            view_angles_rad=geo["view_angles_rad"],
            principal_point_px=((scene.n_cols - 1) / 2.0, 0.0),
            focal_px=geo["focal_px"],
            line_time_s=geo["line_time_s"],
            centre_ground=geo["centre_ground"],
            n_cols=int(scene.n_cols),
            n_rows=int(scene.n_rows),
            first_line_time_s=t_f,
            **options,
        )
