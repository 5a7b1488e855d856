"""The UCL Kepler along-track model (002_0f5a34c3ba5aae9c.txt, section 4.1).

Modified collinearity equations of a pushbroom sequence, ``[0, y - y0, -c]^T = lambda M(t)
(X - X_c(t))``, with one base state vector ``(X0, u)`` shared by every image of an along-track
sequence: image ``i`` is exposed at ``tau = first_line_time_s[i] + row * line_time_s[i]`` after
the sequence epoch, so the fore/aft interval ``dt`` comes from the metadata and is not adjusted.

Orbit. ``(X0, u)`` is the position (m) and *inertial* velocity (m/s) of the perspective centre
at the epoch ``tau = 0``, in the inertial frame that coincides with ECEF at the epoch. Two-body
(Kepler) motion with ``GM = 398600.4415 km^3/s^2`` is propagated exactly by the universal
variable method (:func:`propagate`), valid for arcs up to about one orbital period. Earth
rotation is handled in that frame: a ground point's ECEF coordinates are rotated into it by
``R_z(OMEGA_EARTH * tau)`` at the exposure time. The paper's printed second-order series (whose
divisor should be ``|X0|^3``) is available as ``propagator="taylor2"``; over 52 s it departs
from the two-body orbit by hundreds of metres, which the rotations then have to absorb.

Attitude. The camera-to-inertial rotation is ``R_O(tau) R_P(omega, phi, kappa) R_M``:
``R_O`` the local orbital frame (x along track, y = z x v across track to the left, z radial up;
:func:`jaxgeo.rotations.orbit_frame`), ``R_P = R_x(omega) R_y(phi) R_z(kappa)`` (omega ~ roll
about the track, phi ~ pitch, kappa ~ yaw), ``R_M = R_y(-alpha) R_x(-beta)`` the camera mounting
from the along-track view angle ``alpha`` (+ forward) and across-track angle ``beta`` (+ to the
right of the flight direction, the sign of Z_0 in eq. 4 of 000_). With zero angles the platform
follows the orbit (nadir tracking), so constant angles describe the usual steering. Each angle
is a polynomial of order 0 or 1 in ``tau - t_centre[i]`` (the image's centre time), with static
per-image orders: every row of table 7 of 002_ is expressible. Per image the coefficients are
one vector ``[omega0, phi0, kappa0, <rates of the order-1 angles in omega, phi, kappa order>]``
in rad and rad/s, so the parameter count equals the paper's (12 for a pair with constant
rotations).

Camera. Focal length and pixel size from the metadata, principal point at the centre column
``(n_cols - 1) / 2``; the CCD line lies along the camera y axis; columns grow towards +y::

    x = (n_cols - 1) / 2 + f_px * d_y / (-d_z),   0 = d_x,   d = camera-frame ray to the point

``project`` finds the exposure time of a ground point by Newton's method on ``d_x / -d_z``
(differentiated implicitly, so derivatives of every order are exact; a point whose iteration
does not converge comes back as NaN); ``localize`` is direct: the row gives the time, the
column the ray, which is intersected with the surface of ellipsoidal height ``h``. The orbit
enters every image point as a Taylor polynomial (:func:`taylor_coefficients`) about the epoch
(when all images lie within 120 s of it, e.g. a fore/aft pair) or about each image's centre
time, reached by :func:`propagate`: small programs, exact to float64 within minutes.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PyTree

from .. import geodesy
from ..rotations import orbit_frame
from ._base import AbstractMultiImageModel, AbstractSensorModel, all_inexact
from ._kepler_orbit import (
    GM_M3_S2,
    PROPAGATORS,
    _consistent_height_offset,
    _epoch_state,
    _rotate,
    _taylor2_coefficients,
    _yaw_along_track,
    ecef_to_inertial,
    inertial_to_ecef,
    kepler_mounting,
    propagate,
    propagate_taylor2,
    taylor_coefficients,
    taylor_state,
)
from ._metadata import SceneMetadata
from ._newton import newton_root

__all__ = [
    "KeplerCamera",
    "KeplerImage",
    "KeplerSequence",
    "ecef_to_inertial",
    "inertial_to_ecef",
    "kepler_mounting",
    "propagate",
    "propagate_taylor2",
    "taylor_coefficients",
    "taylor_state",
]

_TIME_ITERATIONS = 20  # exposure-time Newton from the centre line (4 within the image)
_TIME_TOL_S = 1e-13
_TIME_CONVERGED_S = 1e-6  # last step of a converged exposure time (s)
_HEIGHT_ITERATIONS = 3  # ray / height-surface Newton from the (a+h, b+h) ellipsoid
_SERIES_SPAN_S = 120.0  # images within this of the epoch share one series about the epoch


# --- per-image static geometry ------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class KeplerCamera:
    """Static geometry of one image of the sequence (hashable: an ``eqx`` static field).

    ``focal_length_px`` = focal length / pixel size; times in seconds after the sequence
    epoch; ``reference`` ``(lon_deg, lat_deg, h_m)`` a ground point near the scene centre.
    """

    n_cols: int
    n_rows: int
    focal_length_px: float
    line_time_s: float
    first_line_time_s: float
    along_track_angle_deg: float
    across_track_angle_deg: float = 0.0
    reference: tuple[float, float, float] = (0.0, 0.0, 0.0)
    image_id: str = ""

    @property
    def centre_time_s(self) -> float:
        """Exposure time of the centre line (origin of the attitude polynomials)."""
        return self.first_line_time_s + 0.5 * (self.n_rows - 1) * self.line_time_s

    @property
    def last_line_time_s(self) -> float:
        return self.first_line_time_s + (self.n_rows - 1) * self.line_time_s

    @property
    def principal_col(self) -> float:
        return 0.5 * (self.n_cols - 1)

    @classmethod
    def from_metadata(
        cls,
        scene: SceneMetadata,
        focal_length_mm: float | None = None,
        pixel_size_um: float | None = None,
        line_time_s: float | None = None,
    ) -> KeplerCamera:
        """From :class:`SceneMetadata`; arguments override (or supply) missing camera values."""
        values = {
            "focal_length_mm": focal_length_mm or scene.focal_length_mm,
            "pixel_size_um": pixel_size_um or scene.pixel_size_um,
            "line_time_s": line_time_s or scene.line_time_s,
        }
        missing = [k for k, v in values.items() if v is None]
        if missing:
            raise ValueError(
                f"scene {scene.image_id!r}: the Kepler model needs {', '.join(missing)}; give "
                "them in the metadata or as arguments"
            )
        return cls(
            n_cols=scene.n_cols,
            n_rows=scene.n_rows,
            focal_length_px=values["focal_length_mm"] * 1e3 / values["pixel_size_um"],
            line_time_s=float(values["line_time_s"]),
            first_line_time_s=scene.first_line_time_s,
            along_track_angle_deg=scene.along_track_angle_deg,
            across_track_angle_deg=scene.across_track_angle_deg,
            reference=tuple(float(v) for v in scene.center),
            image_id=scene.image_id,
        )


def _check_orders(orders) -> tuple[int, int, int]:
    orders = tuple(int(o) for o in orders)
    if len(orders) != 3 or any(o not in (0, 1) for o in orders):
        raise ValueError(
            f"rotation orders must be three of 0 or 1 (omega, phi, kappa), got {orders}"
        )
    return orders


# --- the sequence ---------------------------------------------------------------------------


class KeplerSequence(AbstractMultiImageModel):
    """One orbit ``(X0, u)`` shared by the images of an along-track sequence, per-image attitude.

    Fields:
        position_m, velocity_m_s: ``(3,)`` base state at the epoch (inertial = ECEF at epoch).
        attitude: one ``(3 + sum(orders[i]),)`` vector per image (module docstring).
        cameras: :class:`KeplerCamera` per image (static).
        orders: ``(omega, phi, kappa)`` polynomial orders per image, each 0 or 1 (static).
        propagator: ``"universal"`` (exact two-body) or ``"taylor2"`` (the paper's series).

    ``sequence.image(i)`` is image ``i`` as an :class:`~jaxgeo.models.AbstractSensorModel`.
    """

    position_m: Float[Array, "3"]
    velocity_m_s: Float[Array, "3"]
    attitude: tuple[Float[Array, " k"], ...]
    cameras: tuple[KeplerCamera, ...] = eqx.field(static=True)
    orders: tuple[tuple[int, int, int], ...] = eqx.field(static=True)
    propagator: str = eqx.field(static=True)

    def __init__(
        self,
        position_m: Float[ArrayLike, "3"],
        velocity_m_s: Float[ArrayLike, "3"],
        attitude: Sequence[Float[ArrayLike, " k"]],
        cameras: Sequence[KeplerCamera],
        orders: Sequence[Sequence[int]],
        propagator: str = "universal",
    ):
        self.position_m = jnp.asarray(position_m, dtype=float)
        self.velocity_m_s = jnp.asarray(velocity_m_s, dtype=float)
        self.attitude = tuple(jnp.asarray(a, dtype=float) for a in attitude)
        self.cameras = tuple(cameras)
        self.orders = tuple(_check_orders(o) for o in orders)
        self.propagator = propagator

    def __check_init__(self):
        if self.propagator not in PROPAGATORS:
            raise ValueError(f"unknown propagator {self.propagator!r}; expected {PROPAGATORS}")
        n = len(self.cameras)
        if n == 0 or len(self.orders) != n or len(self.attitude) != n:
            raise ValueError(
                f"KeplerSequence needs one camera, order triple and attitude vector per image; "
                f"got {n}, {len(self.orders)}, {len(self.attitude)}"
            )
        for i, (att, order) in enumerate(zip(self.attitude, self.orders, strict=True)):
            if att.shape[-1:] != (3 + sum(order),):
                raise ValueError(
                    f"attitude of image {i} with orders {order} must have {3 + sum(order)} "
                    f"coefficients, got shape {att.shape}"
                )

    @property
    def n_images(self) -> int:
        return len(self.cameras)

    @property
    def n_params(self) -> int:
        """Number of adjustable parameters: 6 orbit + 3 + (order-1 rates) per image."""
        return 6 + sum(3 + sum(o) for o in self.orders)

    # --- geometry ----------------------------------------------------------------------

    def state(self, tau_s: Float[ArrayLike, ""]) -> tuple[Float[Array, "3"], Float[Array, "3"]]:
        """Inertial position (m) and velocity (m/s) of the perspective centre at ``tau_s``."""
        fn = propagate if self.propagator == "universal" else propagate_taylor2
        return fn(self.position_m, self.velocity_m_s, tau_s)

    def _expansion_time(self, i: int) -> float:
        """Where image ``i``'s orbit series is expanded (static): the epoch when every image
        lies within :data:`_SERIES_SPAN_S` of it (a stereo pair: one series, no propagation),
        else the image's centre time."""
        times = [t for c in self.cameras for t in (c.first_line_time_s, c.last_line_time_s)]
        if self.propagator == "taylor2" or max(abs(t) for t in times) <= _SERIES_SPAN_S:
            return 0.0
        return self.cameras[i].centre_time_s

    def _anchor(self, i: int) -> Float[Array, "n 3"]:
        """Orbit series of image ``i``: :func:`taylor_coefficients` about
        :meth:`_expansion_time` (the paper's series for ``"taylor2"``)."""
        if self.propagator == "taylor2":
            return _taylor2_coefficients(self.position_m, self.velocity_m_s)
        t0 = self._expansion_time(i)
        state = (self.position_m, self.velocity_m_s) if t0 == 0.0 else self.state(t0)
        return taylor_coefficients(*state)

    def _state_near(self, i: int, anchor, tau):
        return taylor_state(anchor, tau - self._expansion_time(i))

    def angles(self, i: int, tau_s: Float[ArrayLike, ""]) -> Float[Array, "3"]:
        """``(omega, phi, kappa)`` in rad of image ``i`` at ``tau_s``."""
        coeffs = self.attitude[i]
        dt = jnp.asarray(tau_s, dtype=float) - self.cameras[i].centre_time_s
        out, k = [], 3
        for axis, order in enumerate(self.orders[i]):
            angle = coeffs[axis]
            if order == 1:
                angle = angle + coeffs[k] * dt
                k += 1
            out.append(angle)
        return jnp.stack(out)

    def _ray(self, i: int, anchor, ground_ecef, tau):
        """Camera-frame vector from the perspective centre to the ground point at ``tau``:
        ``R_M^T R_P^T R_O^T (R_z(Omega tau) X - X_c(tau))`` applied without matrices."""
        r, v = self._state_near(i, anchor, tau)
        w = ecef_to_inertial(ground_ecef, tau) - r
        z = r / jnp.linalg.norm(r)
        y = jnp.cross(z, v)
        y = y / jnp.linalg.norm(y)
        w = jnp.stack([jnp.dot(w, jnp.cross(y, z)), jnp.dot(w, y), jnp.dot(w, z)])
        omega, phi, kappa = self.angles(i, tau)
        w = _rotate(_rotate(_rotate(w, 0, omega, True), 1, phi, True), 2, kappa, True)
        cam = self.cameras[i]
        return kepler_mounting(cam.along_track_angle_deg, cam.across_track_angle_deg).T @ w

    def _project_one(self, i: int, anchor, ground_ecef):
        cam = self.cameras[i]
        tau = _exposure_time(i, self, anchor, ground_ecef)
        d = self._ray(i, anchor, ground_ecef, tau)
        col = cam.principal_col + cam.focal_length_px * d[1] / -d[2]
        return jnp.stack([col, (tau - cam.first_line_time_s) / cam.line_time_s])

    def project(self, i: int, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        """Ground ``(lon_deg, lat_deg, h_m)`` -> image ``(x, y)`` px of image ``i``."""
        ground = jnp.asarray(ground, dtype=float)
        if ground.shape[-1:] != (3,):
            raise ValueError(
                f"ground coordinates must have a last axis of size 3, got {ground.shape}"
            )
        self._check_index(i)
        anchor = self._anchor(i)
        ecef = geodesy.geodetic_to_ecef(ground).reshape(-1, 3)
        out = jax.vmap(lambda g: self._project_one(i, anchor, g))(ecef)
        return out.reshape(*ground.shape[:-1], 2)

    def _localize_one(self, i: int, anchor, image, h):
        cam = self.cameras[i]
        tau = cam.first_line_time_s + image[1] * cam.line_time_s
        r, v = self._state_near(i, anchor, tau)
        d = kepler_mounting(cam.along_track_angle_deg, cam.across_track_angle_deg) @ jnp.stack(
            [0.0, (image[0] - cam.principal_col) / cam.focal_length_px, -1.0]
        )
        omega, phi, kappa = self.angles(i, tau)
        d = _rotate(_rotate(_rotate(d, 2, kappa), 1, phi), 0, omega)
        d = orbit_frame(r, v) @ d
        origin, d = inertial_to_ecef(r, tau), inertial_to_ecef(d / jnp.linalg.norm(d), tau)
        # start on the ellipsoid (a + h, b + h), then Newton on the geodetic height
        scale = jnp.stack([geodesy.WGS84_A_M + h, geodesy.WGS84_A_M + h, geodesy.WGS84_B_M + h])
        o, e = origin / scale, d / scale
        b, a, c = jnp.dot(o, e), jnp.dot(e, e), jnp.dot(o, o) - 1.0
        lam = (-b - jnp.sqrt(b**2 - a * c)) / a  # NaN where the ray misses the Earth
        for _ in range(_HEIGHT_ITERATIONS):
            lon, lat, height = geodesy.ecef_to_geodetic(origin + lam * d)
            up = geodesy.enu_rotation(lon, lat)[2]
            lam = lam - (height - h) / jnp.dot(d, up)
        ground = geodesy.ecef_to_geodetic(origin + lam * d)
        return ground.at[2].set(jnp.where(jnp.isnan(ground[0]), jnp.nan, h))

    def localize(
        self, i: int, image: Float[ArrayLike, "*batch 2"], h: Float[ArrayLike, "*batch"]
    ) -> Float[Array, "*batch 3"]:
        """Image ``(x, y)`` px of image ``i`` at height ``h`` m -> ground ``(lon_deg, lat_deg,
        h_m)``, directly: the ray of the pixel intersected with the height surface."""
        return self.image(i).localize(image, h)

    def _check_index(self, i: int):
        if not 0 <= i < self.n_images:
            raise IndexError(f"image index {i} out of range for {self.n_images} images")

    def image(self, i: int) -> KeplerImage:
        """Image ``i`` as a sensor model (a view sharing this sequence's parameters)."""
        self._check_index(i)
        return KeplerImage(self, i)

    def images(self) -> tuple[KeplerImage, ...]:
        return tuple(self.image(i) for i in range(self.n_images))

    def adjustable_filter(self) -> PyTree[bool]:
        """The orbit ``(X0, u)`` and every image's attitude (every floating-point leaf)."""
        return all_inexact(self)

    def required_gcps(self, dynamic: PyTree) -> None:
        return None

    def with_orders(self, orders: Sequence[Sequence[int]]) -> KeplerSequence:
        """The same sequence with other rotation orders: constants kept, rates kept or zero."""
        attitude = []
        for i, new in enumerate(orders):
            old_axes = [a for a, o in enumerate(self.orders[i]) if o]
            rates = dict(zip(old_axes, self.attitude[i][3:], strict=True))
            extra = [rates.get(a, jnp.zeros(())) for a, o in enumerate(_check_orders(new)) if o]
            attitude.append(
                jnp.concatenate([self.attitude[i][:3], jnp.stack(extra)])
                if extra
                else self.attitude[i][:3]
            )
        return KeplerSequence(
            self.position_m, self.velocity_m_s, attitude, self.cameras, orders, self.propagator
        )

    # --- initial values ----------------------------------------------------------------

    @classmethod
    def from_metadata(
        cls,
        scenes: Sequence[SceneMetadata],
        orders: Sequence[int] | Sequence[Sequence[int]] = (0, 0, 0),
        focal_length_mm: float | None = None,
        pixel_size_um: float | None = None,
        line_time_s: float | None = None,
        propagator: str = "universal",
        iterations: int = 5,
    ) -> KeplerSequence:
        """Approximate sequence from scene metadata (corners, flying height, view angles, timing).

        Per scene, a circular orbit of radius ``|centre| + flying_height`` is placed so that the
        boresight (view angles, yaw-steered along the ground track given by the corners) hits
        the scene centre at the centre line time, iterating as in 3.3.1 of 000_; the per-scene
        states are propagated to the epoch and averaged. ``kappa0`` of each image aligns the
        CCD across the ground track; ``omega0 = phi0 = 0`` and rates 0. ``orders`` is one triple
        for all images or one per image.
        """
        scenes = list(scenes)
        if not scenes:
            raise ValueError("from_metadata needs at least one scene")
        if np.ndim(orders) == 1:
            orders = [tuple(orders)] * len(scenes)
        if len(orders) != len(scenes):
            raise ValueError(f"got {len(orders)} order triples for {len(scenes)} scenes")
        cameras = [
            KeplerCamera.from_metadata(s, focal_length_mm, pixel_size_um, line_time_s)
            for s in scenes
        ]
        pairs = list(zip(scenes, cameras, strict=True))
        delta = _consistent_height_offset(pairs, iterations)
        states = [_epoch_state(s, c, delta, iterations) for s, c in pairs]
        pos = np.mean([p for p, _ in states], axis=0)
        vel = np.mean([v for _, v in states], axis=0)
        radius = np.linalg.norm(pos)
        vel = vel - np.dot(vel, pos) / radius**2 * pos  # re-circularise
        vel = vel / np.linalg.norm(vel) * np.sqrt(GM_M3_S2 / radius)
        attitude = []
        for (scene, cam), order in zip(pairs, orders, strict=True):
            kappa = _yaw_along_track(scene, cam, pos, vel)
            attitude.append(np.concatenate([[0.0, 0.0, kappa], np.zeros(sum(order))]))
        return cls(pos, vel, attitude, cameras, orders, propagator)


def _along_track(i, tau, args):
    """Along-track focal-plane coordinate ``d_x / -d_z`` of the ground point at ``tau``."""
    sequence, anchor, ground_ecef = args
    d = sequence._ray(i, anchor, ground_ecef, tau)
    return d[0] / -d[2]


def _exposure_time(i, sequence, anchor, ground_ecef):
    """Time at which image ``i`` sees the ground point: Newton on ``_along_track = 0`` from the
    centre line (:func:`~jaxgeo.models.newton_root`, implicit derivatives of every
    order); NaN where it does not converge."""
    tau0 = sequence.cameras[i].centre_time_s
    sol = newton_root(
        functools.partial(_along_track, i),
        tau0,
        (sequence, anchor, ground_ecef),
        max_steps=_TIME_ITERATIONS,
        tol=_TIME_TOL_S,
        converged_tol=_TIME_CONVERGED_S,
    )
    return jnp.where(sol.converged, sol.value, jnp.nan)


class KeplerImage(AbstractSensorModel):
    """Image ``index`` of a :class:`KeplerSequence` as a sensor model (shares its parameters)."""

    sequence: KeplerSequence
    index: int = eqx.field(static=True)

    def project(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        """Ground ``(lon_deg, lat_deg, h_m)`` -> image ``(x, y)`` px."""
        return self.sequence.project(self.index, ground)

    def _localize_point(self, image, h, guess):
        # direct, not the shared Newton: the row gives the time, the column the ray, which
        # meets the height surface (``guess`` is not needed)
        del guess
        anchor = self.sequence._anchor(self.index)
        return self.sequence._localize_one(self.index, anchor, image, h)

    def adjustable_filter(self) -> PyTree[bool]:
        """Every floating-point leaf of the sequence it views."""
        return all_inexact(self)

    def required_gcps(self, dynamic: PyTree) -> None:
        return None

    def reference_ground(self) -> Float[Array, "3"]:
        return jnp.asarray(self.sequence.cameras[self.index].reference)

    @property
    def camera(self) -> KeplerCamera:
        return self.sequence.cameras[self.index]
