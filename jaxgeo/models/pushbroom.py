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
  offset in the platform (m); ``dx = 0`` (compose :class:`~jaxgeo.models.bias.Biased` for
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

import functools
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PyTree

from ..geodesy import (
    GM_EARTH_M3_S2,
    WGS84_A_M,
    WGS84_B_M,
    ecef_to_geodetic,
    geodetic_to_ecef,
)
from ..rotations import orbit_frame, roll_pitch_yaw
from .base import AbstractSensorModel
from .spline import Spline, SplineObservations

if TYPE_CHECKING:  # io sits below models in the layering: only the type is imported
    from ..io.metadata import SceneMetadata

LOCALIZE_NEWTON_STEPS = 3
"""Newton steps on ``(lon, lat)`` in :meth:`GenericPushbroom.localize`: the start, on the
ellipsoid with both semi-axes raised by ``h``, is right to first order in ``h`` (cm at 4 km)."""


def _f64(x) -> Array:
    return jnp.asarray(x, dtype=float)


def mounting_rotation(
    along_track_angle_rad: Float[ArrayLike, "*batch"],
    across_track_angle_rad: Float[ArrayLike, "*batch"],
) -> Float[Array, "*batch 3 3"]:
    """Camera -> platform rotation ``R_M = [X_M, Y_M, Z_M]`` of eq. 4.

    The paper's ``Z_0 = (tan alpha, -tan beta, -1)`` is the viewing direction in the platform
    frame (x along track, y left, z up): forward for ``alpha > 0``, right for ``beta > 0``.
    Two deliberate departures from the printed equation: the camera z axis is *minus* the
    viewing direction (it points from the ground to the sensor, so ``lambda > 0`` in eq. 3 and
    ``x`` grows towards ``+X_M``, the left of the flight: the image as seen from above, not
    mirrored), and ``X_M = (0, cos beta, -sin beta)``: the printed ``cos alpha`` is a typo, that
    vector is neither unit nor orthogonal to ``Z_0`` unless ``alpha = 0``. ``Y_M = Z_M x X_M``.
    """
    a = _f64(along_track_angle_rad)
    b = _f64(across_track_angle_rad)
    a, b = jnp.broadcast_arrays(a, b)
    view = jnp.stack([jnp.tan(a), -jnp.tan(b), -jnp.ones_like(a)], axis=-1)
    z = -view / jnp.linalg.norm(view, axis=-1, keepdims=True)
    x = jnp.stack([jnp.zeros_like(b), jnp.cos(b), -jnp.sin(b)], axis=-1)
    y = jnp.cross(z, x)
    return jnp.stack([x, y, z], axis=-1)


def _solve_small(jac, rhs):
    """``jac^-1 rhs`` for a scalar or a 2 x 2 ``jac``, written out (cheap to differentiate)."""
    if jac.ndim == 0:
        return rhs / jac
    (a, b), (c, d) = jac[0], jac[1]
    return jnp.stack([d * rhs[0] - b * rhs[1], a * rhs[1] - c * rhs[0]]) / (a * d - b * c)


def _value_and_jacobian(fun, x, args):
    """``fun(x, args)`` and its Jacobian in ``x`` from one forward-mode pass."""
    jac, value = jax.jacfwd(lambda y: (fun(y, args),) * 2, has_aux=True)(x)
    return value, jac


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 3))
def _newton_root(fun, x0, args, steps: int):
    """Root of ``fun(x, args)`` (``x`` a scalar or 2-vector) by ``steps`` Newton steps from ``x0``.

    Derivatives of any order are those of the implicit function (``dx = -f_x^-1 f_a da``),
    exact once the iteration has converged; nothing is differentiated through the loop, and
    the start ``x0`` gets no gradient (the root does not depend on it).
    """

    def step(_, x):
        f, jac = _value_and_jacobian(fun, x, args)
        return x - _solve_small(jac, f)

    return jax.lax.fori_loop(0, steps, step, x0)


@_newton_root.defjvp
def _newton_root_jvp(fun, steps, primals, tangents):
    x0, args = primals
    _, d_args = tangents
    x = _newton_root(fun, x0, args, steps)
    f_a = jax.jvp(lambda a: fun(x, a), (args,), (d_args,))[1]
    return x, -_solve_small(jax.jacfwd(fun)(x, args), f_a)


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
        t = _newton_root(
            _scan_offset, jax.lax.stop_gradient(t_centre), (self, ecef, r_m), self.newton_steps
        )
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

    def _localize_one(self, image, h):
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
        lonlat = _newton_root(_ray_offset, start, (origin, across, h), LOCALIZE_NEWTON_STEPS)
        return jnp.concatenate([lonlat, h[None]])

    def localize(
        self,
        image: Float[ArrayLike, "*batch 2"],
        h: Float[ArrayLike, "*batch"],
        guess: Float[ArrayLike, "*batch 2"] | None = None,
    ) -> Float[Array, "*batch 3"]:
        """Image ``(x, y)`` px at ellipsoidal height ``h`` m -> ground ``(lon_deg, lat_deg, h_m)``.

        Direct: the ray of the pixel at ``t(y)`` (no search over time) meets the surface at
        height ``h`` where a few Newton steps on ``(lon, lat)`` put ``(lon, lat, h)`` on the ray,
        from its intersection with the ellipsoid raised by ``h``; implicit derivatives.
        ``guess`` is accepted for the common interface and ignored. A ray that misses the
        Earth, or a NaN input, gives NaN for that point.
        """
        del guess
        image = _f64(image)
        if image.shape[-1:] != (2,):
            raise ValueError(
                f"image coordinates must have a last axis of size 2, got {image.shape}"
            )
        h = _f64(h)
        batch = jnp.broadcast_shapes(image.shape[:-1], h.shape)
        image = jnp.broadcast_to(image, (*batch, 2)).reshape(-1, 2)
        h = jnp.broadcast_to(h, batch).reshape(-1)
        return jax.vmap(self._localize_one)(image, h).reshape(*batch, 3)

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
        geo = _initial_geometry(scene, threshold_m, max_iterations, earth_radius_m)
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


def _initial_geometry(scene, threshold_m, max_iterations, earth_radius_m) -> dict:
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
