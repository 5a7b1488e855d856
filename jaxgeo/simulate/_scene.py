"""Shared machinery of the simulated scenes: vendor errors, point fields, accuracy, output.

Determinism: every random draw comes from one ``numpy.random.Generator(seed)`` in a fixed
order, and what is written is quantised first (model parameters and RPC coefficients to 12
significant digits, lon/lat to 1e-10 deg, heights to 1e-6 m, image coordinates to 1e-6 px), so
the same seed gives bit-identical files even where the last bits of a float computation differ.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import geodesy
from ..bundle.internal import enu_errors  # noqa: F401  (re-used by the scenes' reports)
from ..errors import JaxgeoError
from ..intersect import intersect
from ..io.internal import atomic_write_text
from ..models import RPC, EphemerisModel, localize_points, project_points
from ..rotations import orbit_frame
from ._terrain import Terrain

SIG_DIGITS = 12
LONLAT_DECIMALS = 10
HEIGHT_DECIMALS = 6
IMAGE_DECIMALS = 6


class SimulationError(JaxgeoError, ValueError):
    """A simulation option jaxgeo refuses. ``setting`` names the option at fault (the field of
    the settings object, or the argument): ``str(err)`` says it so, and a front end says it in
    its own words with :meth:`render` (the ``jaxgeo simulate`` command: its flag)."""

    def __init__(self, template: str, setting: str | None = None):
        self.template = template
        self.setting = setting
        super().__init__(self.render())

    def render(self, names: dict[str, str] | None = None) -> str:
        """The message, the setting named by ``names[setting]`` (default: its own name)."""
        if self.setting is None:
            return self.template
        return self.template.format((names or {}).get(self.setting, self.setting))

    def __reduce__(self):
        return (type(self), (self.template, self.setting))


def require(ok, setting: str, requirement: str, value) -> None:
    """Raise a :class:`SimulationError` ``"<setting> must <requirement>, got <value>"`` unless
    ``ok``."""
    if not ok:
        raise SimulationError(f"{{}} must {requirement}, got {value!r}", setting)


def is_int(v) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def is_real(v) -> bool:
    return isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)


def check_finite(settings, *names: str) -> None:
    """Each field ``names`` of ``settings`` a finite number."""
    for n in names:
        v = getattr(settings, n)
        require(is_real(v) and math.isfinite(v), n, "be a finite number", v)


def check_positive(settings, *names: str) -> None:
    """Each field ``names`` of ``settings`` a finite number > 0."""
    for n in names:
        v = getattr(settings, n)
        require(is_real(v) and math.isfinite(v) and v > 0, n, "be a finite number > 0", v)


def check_non_negative(settings, *names: str) -> None:
    """Each field ``names`` of ``settings`` a finite number >= 0."""
    for n in names:
        v = getattr(settings, n)
        require(is_real(v) and math.isfinite(v) and v >= 0, n, "be a finite number >= 0", v)


def check_int(settings, name: str, low: int) -> None:
    """Field ``name`` of ``settings`` an integer >= ``low``."""
    check_int_value(getattr(settings, name), name, low)


def check_int_value(v, name: str, low: int) -> None:
    """``v`` (the setting or argument ``name``) an integer >= ``low``."""
    require(is_int(v), name, "be an integer", v)
    require(v >= low, name, f"be >= {low}", v)


def check_range(settings, name: str, positive: bool = False) -> None:
    """Field ``name`` of ``settings`` a pair of finite numbers ``(low, high)``, ``low <= high``
    (``0 < low`` if ``positive``)."""
    v = getattr(settings, name)
    ok = (
        isinstance(v, tuple | list)
        and len(v) == 2
        and all(is_real(x) and math.isfinite(x) for x in v)
        and v[0] <= v[1]
        and (not positive or v[0] > 0)
    )
    what = "0 < " if positive else ""
    require(ok, name, f"be a pair of finite numbers ({what}low <= high)", v)


def check_numbers(settings, name: str, n: int) -> None:
    """Field ``name`` of ``settings`` ``n`` finite numbers."""
    v = getattr(settings, name)
    ok = (
        isinstance(v, tuple | list)
        and len(v) == n
        and all(is_real(x) and math.isfinite(x) for x in v)
    )
    require(ok, name, f"be {n} finite numbers", v)


def check_epoch(settings, name: str) -> None:
    """Field ``name`` of ``settings`` an ISO 8601 UTC instant (``2006-10-01T00:40:00Z``)."""
    import datetime

    v = getattr(settings, name)
    try:
        datetime.datetime.fromisoformat(v.replace("Z", "+00:00"))
    except (AttributeError, TypeError, ValueError):
        require(False, name, "be an ISO 8601 UTC time such as 2006-10-01T00:40:00Z", v)


def check_rpc_grid(settings, name: str = "rpc_grid") -> None:
    """Field ``name``: the RPC fit grid, three integers (columns, rows, heights) >= 2."""
    v = getattr(settings, name)
    ok = isinstance(v, tuple | list) and len(v) == 3 and all(is_int(x) and x >= 2 for x in v)
    require(ok, name, "be three integers >= 2 (columns, rows, heights)", v)


@dataclasses.dataclass(frozen=True)
class VendorErrors:
    """Errors of the orientation a vendor fits its RPCs to (the "perturbed copy of the truth").

    Angles are given in pixel equivalents (``px * pixel_size / focal_length`` rad), positions in
    metres. ``pitch_px`` is the magnitude range of the common along-track pointing error (random
    sign), the rest are standard deviations: common roll (across track) and yaw, per-camera (or
    per-scene) mounting errors along and across track, an attitude drift per second of scan time
    (roll and pitch), and a constant ephemeris error (along, across, radial). The defaults give
    the ~33 px offsets and ~72 m / 25 m forward-intersection errors of Cartosat-1 (000_, table 3).
    """

    pitch_px: tuple[float, float] = (20.0, 34.0)
    roll_px: float = 5.0
    yaw_rad: float = 2e-5
    mount_along_px: float = 2.5
    mount_across_px: float = 8.0
    drift_px_per_s: float = 0.03
    position_m: tuple[float, float, float] = (10.0, 5.0, 5.0)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


CARTOSAT1_ERRORS = VendorErrors()
"""The default errors of a Cartosat-1 pair (000_ table 3)."""


def round_sig(x, digits: int = SIG_DIGITS) -> np.ndarray:
    """Round every element to ``digits`` significant decimal digits (exactly reproducible)."""
    x = np.asarray(x, dtype=float)
    flat = [float(f"{v:.{digits - 1}e}") for v in x.ravel()]
    return np.asarray(flat, dtype=float).reshape(x.shape)


def quantize_model(model: eqx.Module) -> eqx.Module:
    """``model`` with every float array leaf rounded by :func:`round_sig`."""

    def q(v):
        return (
            jnp.asarray(round_sig(v)) if jnp.issubdtype(jnp.asarray(v).dtype, jnp.floating) else v
        )

    return jax.tree.map(q, model)


def quantize_ground(g: np.ndarray) -> np.ndarray:
    g = np.asarray(g, dtype=float)
    return np.concatenate(
        [np.round(g[..., :2], LONLAT_DECIMALS), np.round(g[..., 2:], HEIGHT_DECIMALS)], axis=-1
    )


def quantize_image(xy: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(xy, dtype=float), IMAGE_DECIMALS)


def px_rad(model: EphemerisModel, px: float) -> float:
    return float(px) * float(model.pixel_size_m) / float(model.focal_length_m)


def draw_common_errors(rng: np.random.Generator, errors: VendorErrors, model: EphemerisModel):
    """One draw of the errors shared by every image of a pass: ``(d_attitude (3, 2), d_pos (3,))``
    -- constant and rate (per unit of normalised time) of omega, phi, kappa, and the ECI
    position offset."""
    sign = rng.choice([-1.0, 1.0])
    pitch = sign * rng.uniform(*errors.pitch_px)
    roll = rng.normal(0.0, errors.roll_px)
    yaw = rng.normal(0.0, errors.yaw_rad)
    drift = rng.normal(0.0, errors.drift_px_per_s, 2) * float(model.t_scale_s)
    d_att = np.array(
        [
            [px_rad(model, roll), px_rad(model, drift[0])],
            [px_rad(model, pitch), px_rad(model, drift[1])],
            [yaw, 0.0],
        ]
    )
    local = rng.normal(0.0, 1.0, 3) * np.asarray(errors.position_m)
    pos, vel = np.asarray(model.position_coeffs)[:, 0], np.asarray(model.velocity_coeffs)[:, 0]
    d_pos = np.asarray(orbit_frame(pos, vel)) @ local  # at t_ref (tau = 0)
    return d_att, d_pos


def draw_mount_errors(rng: np.random.Generator, errors: VendorErrors, model, n: int):
    """``(n, 3)`` view-angle errors (along, across, 0) in radians, one row per camera/scene."""
    along = rng.normal(0.0, errors.mount_along_px, n)
    across = rng.normal(0.0, errors.mount_across_px, n)
    return np.stack([px_rad(model, 1.0) * along, px_rad(model, 1.0) * across, np.zeros(n)], -1)


def perturb(model: EphemerisModel, d_att, d_pos, d_view) -> EphemerisModel:
    """``model`` with attitude, ephemeris and mounting errors added."""
    att = np.array(model.attitude_coeffs)
    att[:, : d_att.shape[1]] += d_att
    pos = np.array(model.position_coeffs)
    pos[:, 0] += d_pos
    return dataclasses.replace(
        model,
        attitude_coeffs=jnp.asarray(att),
        position_coeffs=jnp.asarray(pos),
        view_angles_rad=model.view_angles_rad + jnp.asarray(d_view),
    )


def points_on_terrain(model, image, terrain: Terrain, iterations: int = 30) -> np.ndarray:
    """``(n, 3)`` points on ``terrain`` whose rays from ``image`` ``(n, 2)`` px meet it.

    Fixed-point iteration in height (localise, read the terrain), which converges where the
    terrain slope times the tangent of the view angle is below one (true of smooth terrain).
    """
    image = np.asarray(image, dtype=float)
    h = np.full(len(image), 0.5 * float(terrain.h_min_m + terrain.h_max_m))
    for _ in range(iterations):
        g = localize(model, image, h)
        h = terrain.height_np(g[:, :2])
    g = localize(model, image, h)
    return quantize_ground(np.concatenate([g[:, :2], terrain.height_np(g[:, :2])[:, None]], -1))


project = project_points
"""Jitted, chunked ``model.project`` (:func:`jaxgeo.models.project_points`)."""

localize = localize_points
"""Jitted, chunked ``model.localize`` (:func:`jaxgeo.models.localize_points`)."""


def ground_noise(rng: np.random.Generator, ground: np.ndarray, sigma_m: float) -> np.ndarray:
    """``ground`` moved by independent N(0, sigma) east, north and up offsets (a GPS survey)."""
    enu = rng.normal(0.0, sigma_m, ground.shape)
    rot = np.asarray(geodesy.enu_rotation(ground[:, 0], ground[:, 1]))
    ecef = np.asarray(geodesy.geodetic_to_ecef(ground)) + np.einsum("nji,nj->ni", rot, enu)
    return quantize_ground(np.asarray(geodesy.ecef_to_geodetic(ecef)))


def spread_selection(xy: np.ndarray, k: int) -> np.ndarray:
    """Indices of ``k`` points of ``xy`` ``(n, 2)`` spread evenly (nearest to a grid of targets)."""
    n = len(xy)
    k = min(int(k), n)
    if k <= 0:
        return np.zeros(0, dtype=int)
    side = math.ceil(math.sqrt(k))
    lo, hi = xy.min(0), xy.max(0)
    u = (np.arange(side) + 0.5) / side
    targets = lo + (hi - lo) * np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)
    order = np.argsort(np.linalg.norm(targets - 0.5 * (lo + hi), axis=-1), kind="stable")
    chosen: list[int] = []
    for t in targets[order][:k]:
        d = np.linalg.norm(xy - t, axis=-1)
        d[chosen] = np.inf
        chosen.append(int(np.argmin(d)))
    return np.sort(np.asarray(chosen))


# ------------------------------------------------------------------------------ accuracy


def forward_intersect(rpcs: list[RPC], image: np.ndarray) -> np.ndarray:
    """Intersect measurements ``image`` ``(k, n, 2)`` of ``n`` points in ``k`` images
    (:func:`jaxgeo.intersect.intersect`, the one forward intersection of the package)."""
    return np.asarray(intersect(rpcs, np.swapaxes(image, 0, 1), sigma_px=1.0).ground)


def rms(x: np.ndarray, axis=0) -> np.ndarray | float:
    return np.sqrt(np.mean(np.square(x), axis=axis))


# -------------------------------------------------------------------------------- output


def check_writable(paths: list[pathlib.Path], overwrite: bool) -> None:
    """Refuse (before anything is written) if any output exists and ``overwrite`` is False."""
    if overwrite:
        return
    existing = [str(p) for p in paths if p.exists()]
    if existing:
        raise FileExistsError(
            f"refusing to overwrite existing file(s): {', '.join(existing)} (use --overwrite)"
        )


def write_json(path: str | os.PathLike, obj, overwrite: bool) -> pathlib.Path:
    text = json.dumps(obj, indent=1, sort_keys=False, allow_nan=False) + "\n"
    return atomic_write_text(path, text, overwrite=overwrite)


def rounded(x, decimals: int = 6):
    """Plain nested lists/floats rounded to ``decimals`` (for the JSON reports)."""
    if isinstance(x, dict):
        return {k: rounded(v, decimals) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [rounded(v, decimals) for v in x]
    if isinstance(x, np.ndarray):
        return rounded(x.tolist(), decimals)
    if isinstance(x, (float, np.floating)):
        return float(round(float(x), decimals))
    if isinstance(x, np.integer):
        return int(x)
    return x


def truth_tail(scene) -> dict:
    """The part of ``truth.json`` every simulated scene shares: terrain, true ground points, true
    image measurements and the vendor models' accuracy (keys in this order)."""
    return {
        "terrain": scene.terrain.to_dict(),
        "points": {
            "ids": list(scene.ground.ids),
            "role": list(scene.ground.role),
            "lonlath_true": scene.ground_true.tolist(),
        },
        "image_true": [
            [p, i, float(x), float(y)]
            for p, i, (x, y) in zip(
                scene.image_true.point_ids,
                scene.image_true.images,
                scene.image_true.xy,
                strict=True,
            )
        ],
        "vendor_accuracy": scene.accuracy(),
    }
