"""The true models of a simulated pushbroom stereo scene: a Pleiades-like along-track pair, its
attitude jitter, the vendor's perturbed copy and the RPCs fitted to it.

One agile platform on a 694 km sun-synchronous, descending orbit (f = 12.905 m) images the site
twice in one pass: ``left`` looking forward (along-track view angle ``+view_angle_deg``), then
``right`` looking backward (``-view_angle_deg``); 12 um pixels give a GSD of about 0.66 m and the
line time is set for square ground pixels. Each image is an
:class:`~jaxgeo.models.EphemerisModel` (the orbit and attitude polynomials fitted to the circular
orbit and its yaw-steering law, plus a smooth random attitude wobble), its principal column
shifted so that the site centre is seen in the middle column (the pointing of an agile platform).

Jitter (:class:`JitteredModel`): the platform's attitude oscillates,
``roll(t) = A_x sin(2 pi t / T + phi_x)`` and ``pitch(t) = A_y sin(2 pi t / T + phi_y)`` with
``T = period_lines * line_time``. An attitude rotation ``delta`` of a pushbroom camera moves
every pixel of the line being acquired by ``f delta / pixel_size`` pixels (across track for roll,
along track for pitch), the same for every pixel to within ``1e-4`` of itself over the field of
view and independent of the terrain; :class:`JitteredModel` applies that displacement exactly, as
a function of the acquisition time (the row): the pixel ``(x, y)`` of the jittered image looks
where the jitter-free model's pixel ``(x, y) - a(y)`` looks. Both images share the one platform
oscillation (their phases follow from their acquisition times). Amplitudes are given in pixels:
``A_x = jitter_px`` (across track) and ``A_y = JITTER_ALONG_RATIO * jitter_px`` (along track).

The vendor (:func:`vendor_rpcs`) fits terrain-independent RPCs (:func:`~jaxgeo.models.fit_rpcs`)
to the jitter-free models, as a vendor's smooth attitude cannot hold the jitter; by default to a
copy perturbed by small pointing and ephemeris errors (:data:`PLEIADES_ERRORS`: a few pixels of
bias, as delivered RPCs have), or to the exact ones (``exact=True``).
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PyTree

from .. import geodesy
from ..models import RPC, AbstractSensorModel, EphemerisModel, RPCFitReport, fit_rpcs
from ..models.internal import gmst_rad
from ..models.internal import nothing as _nothing
from . import _scene as sc
from ._orbit import (
    CircularOrbit,
    EphemerisSettings,
    ephemeris_from_orbit,
    sun_synchronous_inclination_deg,
)
from ._render import _intersect_chunk, terrain_bracket
from ._stereo_scene_texture import ProceduralTexture
from ._terrain import Terrain

NAMES = ("left", "right")
JITTER_ALONG_RATIO = 0.25
"""Along-track (pitch) jitter amplitude as a fraction of the across-track (roll) one."""
JITTER_ITERATIONS = 8
"""Fixed-point steps of :meth:`JitteredModel.project` (contraction ``2 pi A_y / P``, < 0.01)."""

PLEIADES_ERRORS = sc.VendorErrors(
    pitch_px=(1.0, 3.0),
    roll_px=1.5,
    yaw_rad=2e-6,
    mount_along_px=0.5,
    mount_across_px=0.5,
    drift_px_per_s=0.0,
    position_m=(0.5, 0.5, 0.5),
)
"""The vendor's orientation errors of the simulated Pleiades-like pair: a common pointing error
of 1-3 px along track and ~1.5 px across, half a pixel of mounting and ephemeris error, which
gives delivered RPCs biased by a few pixels (what the bias compensation of ``jaxgeo adjust``
removes)."""


class JitteredModel(AbstractSensorModel):
    """``model`` with a sinusoidal line-of-sight jitter (module docstring): image point
    ``(x, y)`` of this model looks where ``model``'s ``(x, y) - a(y)`` looks, with
    ``a(y) = amplitude_px * sin(2 pi y / period_lines + phase_rad)`` (x and y components)."""

    model: AbstractSensorModel
    amplitude_px: Float[Array, "2"]
    period_lines: Float[Array, ""]
    phase_rad: Float[Array, "2"]

    def __init__(self, model, amplitude_px, period_lines, phase_rad):
        self.model = model
        self.amplitude_px = jnp.asarray(amplitude_px, dtype=float)
        self.period_lines = jnp.asarray(period_lines, dtype=float)
        self.phase_rad = jnp.asarray(phase_rad, dtype=float)

    def offset_px(self, row: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch 2"]:
        """The jitter displacement ``a(y)`` (px, x and y) of the line acquired at row ``y``."""
        arg = 2.0 * jnp.pi * jnp.asarray(row, dtype=float)[..., None] / self.period_lines
        return self.amplitude_px * jnp.sin(arg + self.phase_rad)

    def offset_px_np(self, row: np.ndarray) -> np.ndarray:
        """:meth:`offset_px` in numpy (host side, for the renderer)."""
        arg = 2.0 * np.pi * np.asarray(row, dtype=float)[..., None] / float(self.period_lines)
        return np.asarray(self.amplitude_px) * np.sin(arg + np.asarray(self.phase_rad))

    def project(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        """The row ``y`` solving ``y - a_y(y) = y0`` (fixed point), then ``x0 + a_x(y)``."""
        xy0 = self.model.project(ground)
        y = xy0[..., 1]
        for _ in range(JITTER_ITERATIONS):
            y = xy0[..., 1] + self.offset_px(y)[..., 1]
        return xy0 + self.offset_px(y)

    def _localize_point(self, image, h, guess):
        return self.model.localize(image - self.offset_px(image[1]), h, guess)

    def reference_ground(self) -> Float[Array, "3"]:
        return self.model.reference_ground()

    def adjustable_filter(self) -> PyTree[bool]:
        """Nothing: a simulation's truth, not a model to adjust."""
        return _nothing(self)

    def required_gcps(self, dynamic: PyTree) -> None:
        return None

    def to_dict(self) -> dict:
        return {
            "amplitude_px": np.asarray(self.amplitude_px).tolist(),
            "period_lines": float(self.period_lines),
            "phase_rad": np.asarray(self.phase_rad).tolist(),
        }


def _centre_time(model: EphemerisModel, ground: np.ndarray) -> float:
    row = float(np.asarray(sc.project(model, ground))[1])
    return float(model.first_line_time_s) + row * float(model.line_time_s)


@dataclasses.dataclass(frozen=True)
class PleiadesSettings:
    """The platform of :func:`pleiades_pair` (module docstring): along-track view angle of the
    two images (``+-view_angle_deg``), orbit ``altitude_m``, camera (``focal_length_m``,
    ``pixel_size_m``), the pass's ``epoch_utc`` and the size of the attitude wobble."""

    view_angle_deg: float = 11.3
    altitude_m: float = 694e3
    focal_length_m: float = 12.905
    pixel_size_m: float = 12e-6
    epoch_utc: str = "2021-06-15T10:30:00Z"
    attitude_wobble_rad: float = 2e-6

    def __post_init__(self):
        sc.check_finite(self, "view_angle_deg")
        sc.check_positive(self, "altitude_m", "focal_length_m", "pixel_size_m")
        sc.check_non_negative(self, "attitude_wobble_rad")
        sc.check_epoch(self, "epoch_utc")


def pleiades_pair(
    rng: np.random.Generator,
    size: int,
    centre_lon_deg: float,
    centre_lat_deg: float,
    h_mid_m: float,
    settings: PleiadesSettings = PleiadesSettings(),
) -> dict[str, EphemerisModel]:
    """The jitter-free true models ``{"left", "right"}`` of a ``size`` x ``size`` px pair
    centred on the site (module docstring) seen by the platform ``settings``; one draw from
    ``rng`` (the attitude wobble)."""
    s = settings
    view_angle_deg, altitude_m = s.view_angle_deg, s.altitude_m
    focal_length_m, pixel_size_m = s.focal_length_m, s.pixel_size_m
    lon, lat = float(centre_lon_deg), float(centre_lat_deg)
    theta0 = gmst_rad(s.epoch_utc)
    orbit = CircularOrbit.over(
        lon, lat, altitude_m, sun_synchronous_inclination_deg(altitude_m), theta0
    )
    target = np.array([lon, lat, h_mid_m])
    v_ground = orbit.mean_motion_rad_s * geodesy.WGS84_A_M
    angles = (view_angle_deg, -view_angle_deg)
    slant = altitude_m / math.cos(math.radians(view_angle_deg))
    line_time = slant * pixel_size_m / focal_length_m / v_ground  # square pixels, refined below
    camera = EphemerisSettings(
        sidereal_angle_rad=theta0, line_time_s=line_time, n_rows=size, n_cols=size,
        focal_length_m=focal_length_m, pixel_size_m=pixel_size_m, position_order=3,
        attitude_order=5, h_ref_m=h_mid_m,
    )  # fmt: skip
    centre = np.array([(size - 1) / 2.0] * 2)
    for _ in range(2):  # line time for square ground pixels, then the scan times of the site
        duration = (size - 1) * line_time
        camera = dataclasses.replace(camera, line_time_s=line_time)
        times, provisional = [], []
        for angle in angles:
            t = -altitude_m * math.tan(math.radians(angle)) / v_ground
            for _ in range(2):
                model = ephemeris_from_orbit(
                    orbit, (t - 60, t + 60), camera, first_line_time_s=t - duration / 2,
                    view_angles_deg=(angle, 0.0, 0.0),
                )  # fmt: skip
                t = _centre_time(model, target)
            times.append(t)
            provisional.append(model)
        g = sc.localize(provisional[0], np.stack([centre, centre + [1, 0], centre + [0, 1]]),
                        h_mid_m)  # fmt: skip
        e = np.asarray(_ecef(g))
        line_time *= np.linalg.norm(e[1] - e[0]) / np.linalg.norm(e[2] - e[0])
    duration = (size - 1) * line_time
    camera = dataclasses.replace(camera, line_time_s=line_time)
    span = (min(times) - 10.0, max(times) + 10.0)
    wobble = rng.normal(0.0, s.attitude_wobble_rad, (3, 3)) / np.arange(1, 4)
    out = {}
    for name, angle, t in zip(NAMES, angles, times, strict=True):
        model = ephemeris_from_orbit(
            orbit, span, camera, first_line_time_s=t - duration / 2,
            view_angles_deg=(angle, 0.0, 0.0), attitude_offsets_rad=wobble,
        )  # fmt: skip
        col = float(np.asarray(sc.project(model, target))[0])
        shift = 0.5 * (size - 1) - col  # the columns are linear in the principal column
        model = eqx.tree_at(lambda m: m.principal_col_px, model, model.principal_col_px + shift)
        out[name] = sc.quantize_model(model)
    return out


def draw_ground(
    rng: np.random.Generator, pair: dict[str, EphemerisModel], size: int, h_range_m, site_lonlat
) -> tuple[Terrain, ProceduralTexture]:
    """The terrain over the footprint of ``pair`` (``size`` px images; heights ``h_range_m``)
    and its texture about ``site_lonlat`` (deg): the draws a stereo scene makes from its ``rng``
    after its pair's."""
    h_mid = 0.5 * (h_range_m[0] + h_range_m[1])
    lon, lat = (float(v) for v in site_lonlat)
    corners = np.array([[0, 0], [size - 1, 0], [0, size - 1], [size - 1, size - 1]], float)
    foot = np.concatenate([sc.localize(m, corners, h_mid)[:, :2] for m in pair.values()])
    footprint_m = size * 0.67
    wavelengths = (max(footprint_m / 5.0, 100.0), max(3.0 * footprint_m, 1000.0))
    terrain = Terrain.random(rng, foot, h_range_m, n_waves=8, wavelength_range_m=wavelengths)
    return terrain, ProceduralTexture(lon, lat, int(rng.integers(0, 2**32)))


def jitter_phases(models: dict[str, EphemerisModel], period_lines: float, phi_xy) -> dict:
    """Per image, the phase (rad, x and y) of the platform's oscillation
    ``sin(2 pi t / T + phi_xy)`` in the image's own row: ``T = period_lines * line_time``."""
    out = {}
    for name, m in models.items():
        period_s = float(period_lines) * float(m.line_time_s)
        t0 = float(m.first_line_time_s)
        out[name] = np.mod(2.0 * np.pi * t0 / period_s + np.asarray(phi_xy, float), 2.0 * np.pi)
    return out


def true_models(
    base: dict[str, EphemerisModel], jitter_px: float, period_lines: float, phases: dict
) -> dict[str, AbstractSensorModel]:
    """The models the images are rendered with: ``base`` itself without jitter, else each
    wrapped in a :class:`JitteredModel`."""
    if jitter_px == 0.0:
        return dict(base)
    amplitude = np.array([1.0, JITTER_ALONG_RATIO]) * float(jitter_px)
    return {n: JitteredModel(m, amplitude, period_lines, phases[n]) for n, m in base.items()}


def vendor_rpcs(
    rng: np.random.Generator,
    base: dict[str, EphemerisModel],
    h_range_m: tuple[float, float],
    exact: bool,
    errors: sc.VendorErrors = PLEIADES_ERRORS,
) -> tuple[dict[str, EphemerisModel], dict[str, RPC], dict[str, RPCFitReport]]:
    """The vendor's models (``base`` perturbed by ``errors``, or ``base`` itself if ``exact``;
    the errors are drawn from ``rng`` either way, so ``exact`` changes nothing else) and the
    RPCs fitted to them over the images and ``h_range_m``, with the fit reports."""
    first = base[NAMES[0]]
    d_att, d_pos = sc.draw_common_errors(rng, errors, first)
    d_view = sc.draw_mount_errors(rng, errors, first, len(NAMES))
    if exact:
        vendor = dict(base)
    else:
        vendor = {
            n: sc.quantize_model(sc.perturb(base[n], d_att, d_pos, d_view[i]))
            for i, n in enumerate(NAMES)
        }
    fits = fit_rpcs([vendor[n] for n in NAMES], h_range=h_range_m)
    rpcs = {n: sc.quantize_model(rpc) for n, (rpc, _) in zip(NAMES, fits, strict=True)}
    reports = {n: rep for n, (_, rep) in zip(NAMES, fits, strict=True)}
    return vendor, rpcs, reports


INTERSECT_CHUNK = 2048
"""Lines per call of the jitted terrain intersection (one compiled shape)."""


def intersect_lines(
    terrain: Terrain, g_lo: np.ndarray, g_hi: np.ndarray, h_range: tuple[float, float]
) -> np.ndarray:
    """:func:`~jaxgeo.simulate._render.intersect_terrain` (a march in height steps of at most
    40 m, at least 16 of them: one compiled program for reliefs up to 600 m; then 10 safeguarded
    Newton steps) in chunks of :data:`INTERSECT_CHUNK` lines: ``(n, 3)``, NaN where none."""
    n = len(g_lo)
    n_march = max(int(math.ceil((h_range[1] - h_range[0]) / 40.0)), 16)
    pad = -n % INTERSECT_CHUNK
    lo = np.concatenate([g_lo, np.repeat(g_lo[:1], pad, 0)])
    hi = np.concatenate([g_hi, np.repeat(g_hi[:1], pad, 0)])
    out = [
        np.asarray(_intersect_chunk(terrain, jnp.asarray(lo[k : k + INTERSECT_CHUNK]),
                                    jnp.asarray(hi[k : k + INTERSECT_CHUNK]), n_march, 10))
        for k in range(0, n + pad, INTERSECT_CHUNK)
    ]  # fmt: skip
    return np.concatenate(out)[:n]


def smooth_part(model: AbstractSensorModel, xy: np.ndarray):
    """``(model without its jitter, image points of it)``: for a :class:`JitteredModel` its
    wrapped model and ``xy - a(y)`` (host side, exact), else ``model`` and ``xy``."""
    if isinstance(model, JitteredModel):
        return model.model, xy - model.offset_px_np(xy[:, 1])
    return model, xy


def project_true(model: AbstractSensorModel, ground: ArrayLike) -> np.ndarray:
    """``model.project`` of ``(n, 3)`` points, jitted through the wrapped model for a
    :class:`JitteredModel` (its fixed point on the row in numpy): no compilation per wrapper."""
    if not isinstance(model, JitteredModel):
        return sc.project(model, ground)
    xy0 = sc.project(model.model, ground)
    y = xy0[:, 1]
    for _ in range(JITTER_ITERATIONS):
        y = xy0[:, 1] + model.offset_px_np(y)[:, 1]
    return xy0 + model.offset_px_np(y)


def localize_on_terrain_exact(
    model: AbstractSensorModel, terrain: Terrain, xy: ArrayLike
) -> np.ndarray:
    """``(n, 3)`` lon/lat/h where the lines of sight of image points ``xy`` ``(n, 2)`` first
    meet ``terrain`` (NaN where none): each line from the model's own localisations at two
    heights bracketing the terrain (no node-grid interpolation)."""
    smooth, xy = smooth_part(model, np.asarray(xy, dtype=float).reshape(-1, 2))
    h_range = terrain_bracket(terrain)
    g_lo, g_hi = (sc.localize(smooth, xy, h) for h in h_range)
    return intersect_lines(terrain, g_lo, g_hi, h_range)


def base_to_height(models: dict[str, EphemerisModel], ground: ArrayLike, gsd_m: float) -> float:
    """Base-to-height ratio of the pair at ``ground``, from the parallax: a height change ``dh``
    moves the point by ``B/H * dh / gsd_m`` pixels in one image relative to the other."""
    g = np.asarray(ground, dtype=float)
    pts = np.stack([g - [0, 0, 5.0], g + [0, 0, 5.0]])
    a, b = (sc.project(m, pts) for m in models.values())
    parallax = (a[1] - b[1]) - (a[0] - b[0])
    return float(np.linalg.norm(parallax) / 10.0 * gsd_m)


def pixel_size_on_ground_m(model: AbstractSensorModel, xy: ArrayLike, h: float) -> float:
    """Geometric mean (m) of the ground distances between pixel ``xy`` and its right and lower
    neighbours at height ``h`` (jitted: no op-by-op dispatch)."""
    xy = np.asarray(xy, dtype=float)
    e = np.asarray(_ecef(sc.localize(model, np.stack([xy, xy + [1, 0], xy + [0, 1]]), h)))
    return float(math.sqrt(np.linalg.norm(e[1] - e[0]) * np.linalg.norm(e[2] - e[0])))


@eqx.filter_jit
def _ecef(ground):
    return geodesy.geodetic_to_ecef(ground)
