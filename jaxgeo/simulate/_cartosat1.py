"""Simulated Cartosat-1 along-track stereo pairs (000_ and 002_, tables 1).

One platform on a 618 km sun-synchronous orbit carries the fore (+26 deg) and aft (-5 deg)
cameras (f = 1945 mm, 7 um pixels, 12 000 x 12 000 px, line time 0.336 ms); the body is
yaw-steered so both sweep the same ground strip, about 52 s apart. The truth is one
:class:`~jaxgeo.models.EphemerisModel` per camera sharing the orbit and attitude polynomials. The
"vendor" RPCs are fitted (terrain-independent, :func:`jaxgeo.fit_rpc`) to a perturbed copy of
the truth (:class:`~jaxgeo.simulate._scene.VendorErrors`), so they carry the tens-of-pixels bias
the papers report. Ground points are a GPS field on a smooth synthetic terrain; image
measurements are the true projections plus Gaussian noise.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib

import equinox as eqx
import numpy as np

from .. import geodesy
from ..io import GroundPoints, Observations, write_ground, write_observations
from ..models import RPC, EphemerisModel, RPCFitReport, fit_rpcs
from ..models.internal import gmst_rad
from . import _scene as sc
from ._orbit import (
    CircularOrbit,
    EphemerisSettings,
    ephemeris_from_orbit,
    sun_synchronous_inclination_deg,
)
from ._terrain import Terrain

SITES = {
    # Hobart (000_): 69 GPS points in the top-left quarter, sea level to 1260 m
    "hobart": dict(lon=147.30, lat=-42.88, h_range=(0.0, 1260.0), n_points=69, layout="quarter"),
    # Warsaw (002_): 36 well-distributed points, flat
    "warsaw": dict(lon=21.01, lat=52.23, h_range=(75.0, 160.0), n_points=36, layout="grid"),
}
NAMES = ("fore", "aft")


def stereo_output_files(directory: str | os.PathLike) -> list[pathlib.Path]:
    """The files :meth:`StereoScene.save` writes."""
    d = pathlib.Path(directory)
    return [d / f"{n}.txt" for n in NAMES] + [
        d / "ground.csv",
        d / "observations.csv",
        d / "truth.json",
    ]


@dataclasses.dataclass(frozen=True)
class StereoScene:
    """A simulated stereo pair: truth, vendor RPCs, ground points and image measurements.

    ``ground`` holds the surveyed (noisy) coordinates with roles ``gcp`` / ``check``;
    ``ground_true`` the true ones (same order). ``observations`` are the noisy measurements,
    ``image_true`` the exact projections of ``ground_true`` (same rows, sigma 0).
    """

    names: tuple[str, ...]
    truth: dict[str, EphemerisModel]
    vendor_models: dict[str, EphemerisModel]
    vendor: dict[str, RPC]
    fit_reports: dict[str, RPCFitReport]
    ground: GroundPoints
    ground_true: np.ndarray
    observations: Observations
    image_true: Observations
    terrain: Terrain
    params: dict

    def accuracy(self) -> dict:
        """Direct georeferencing with the vendor RPCs against truth (000_, table 3).

        Image: RMS (x, y and length) of ``vendor.project(ground_true) - image_true`` per image.
        Object: forward intersection of the measurements with the vendor RPCs, RMS east,
        north, planimetric and height error in metres.
        """
        out: dict = {"image_px": {}}
        for name in self.names:
            res = np.asarray(sc.project(self.vendor[name], self.ground_true)) - self._true(name)
            rx, ry = sc.rms(res)
            out["image_px"][name] = {"rms_x": rx, "rms_y": ry, "rms": math.hypot(rx, ry)}
        obs = np.stack([self._measured(name) for name in self.names])
        est = sc.forward_intersect([self.vendor[n] for n in self.names], obs)
        e, n, u = sc.rms(sc.enu_errors(est, self.ground_true))
        out["intersection_m"] = {"rms_e": e, "rms_n": n, "rms_plan": math.hypot(e, n), "rms_h": u}
        return sc.rounded(out)

    def _rows(self, obs: Observations, name: str) -> np.ndarray:
        index = {pid: i for i, pid in enumerate(self.ground.ids)}
        sel = [i for i, img in enumerate(obs.images) if img == name]
        order = np.argsort([index[obs.point_ids[i]] for i in sel])
        return obs.xy[np.asarray(sel)[order]]

    def _true(self, name: str) -> np.ndarray:
        return self._rows(self.image_true, name)

    def _measured(self, name: str) -> np.ndarray:
        return self._rows(self.observations, name)

    def files(self, directory: str | os.PathLike) -> list[pathlib.Path]:
        return stereo_output_files(directory)

    def save(self, directory: str | os.PathLike, overwrite: bool = False) -> list[pathlib.Path]:
        """Write ``fore.txt``, ``aft.txt`` (Cartosat-1 ``_RPC.TXT`` layout), ``ground.csv``,
        ``observations.csv`` and ``truth.json`` into ``directory``; refuses to replace any
        existing file unless ``overwrite`` (checked before anything is written)."""
        from ..io import write_rpc_text

        paths = self.files(directory)
        sc.check_writable(paths, overwrite)
        pathlib.Path(directory).mkdir(parents=True, exist_ok=True)
        for name, path in zip(self.names, paths, strict=False):
            write_rpc_text(self.vendor[name], path, overwrite=overwrite)
        write_ground(self.ground, paths[-3], overwrite=overwrite)
        write_observations(self.observations, paths[-2], overwrite=overwrite)
        sc.write_json(paths[-1], self.truth_json(), overwrite)
        return paths

    def truth_json(self) -> dict:
        return {
            "generator": "jaxgeo.simulate.cartosat1_stereo",
            "params": self.params,
            "images": {
                n: {
                    "rpc_file": f"{n}.txt",
                    "truth_model": self.truth[n].to_dict(),
                    "vendor_model": self.vendor_models[n].to_dict(),
                    "rpc_fit": sc.rounded(self.fit_reports[n].to_dict(), 9),
                }
                for n in self.names
            },
            **sc.truth_tail(self),
        }


def _centre_time(model: EphemerisModel, ground: np.ndarray) -> float:
    """Scan time at which ``model`` sees ``ground``."""
    row = float(np.asarray(sc.project(model, ground))[1])
    return float(model.row_time(row))


@dataclasses.dataclass(frozen=True)
class Cartosat1Settings:
    """The options of :func:`cartosat1_stereo` (a Cartosat-1 pair; module docstring).

    ``site`` ``"hobart"`` (69 points in the top-left quarter, relief 0..1260 m, 000_) or
    ``"warsaw"`` (36 points on a jittered grid over the common area, flat, 002_) sets the
    defaults of ``centre_*``, ``h_range_m``, ``n_points`` and ``layout`` (``"quarter"`` or
    ``"grid"``); ``None`` takes the site's. ``n_gcps`` points spread over the field get role
    ``gcp``, the rest ``check``; measurements get Gaussian noise ``image_noise_px`` and the
    a-priori sigma ``image_sigma_px``, surveyed points ``ground_noise_m`` and
    ``ground_sigma_m``. ``vendor_errors``: what the vendor's orientation gets wrong
    (:class:`VendorErrors`). The mission: ``altitude_m``, the fore and aft along-track
    ``view_angles_deg``, the camera (``focal_length_m``, ``pixel_size_m``, ``line_time_s``,
    ``n_rows`` x ``n_cols`` px), the pass's ``epoch_utc`` and the polynomial orders of the
    truth. ``attitude_wobble_rad`` is the size of the true attitude's smooth departure from
    ideal yaw steering; ``rpc_grid`` the vendor's RPC fit grid (columns, rows, heights).
    ``terrain_wavelengths_m``: the range of the terrain's wavelengths (shorter ones for small
    images, whose footprint is a few kilometres). ``centre_columns``: shift each camera's
    principal column so that the site centre is seen in the middle column (a window of a longer
    CCD; without it the Earth's rotation between the fore and aft passes moves the aft
    footprint ~270 px across, which matters only in small images). Checked when made: a bad
    value raises :class:`SimulationError` naming the field.
    """

    site: str = "hobart"
    centre_lon_deg: float | None = None
    centre_lat_deg: float | None = None
    h_range_m: tuple[float, float] | None = None
    n_points: int | None = None
    layout: str | None = None
    n_gcps: int = 9
    image_noise_px: float = 0.3
    image_sigma_px: float = 0.5
    ground_noise_m: float = 0.1
    ground_sigma_m: float = 0.3
    vendor_errors: sc.VendorErrors = sc.CARTOSAT1_ERRORS
    altitude_m: float = 618e3
    view_angles_deg: tuple[float, float] = (26.0, -5.0)
    focal_length_m: float = 1.945
    pixel_size_m: float = 7e-6
    line_time_s: float = 0.336e-3
    n_rows: int = 12000
    n_cols: int = 12000
    epoch_utc: str = "2006-10-01T00:40:00Z"
    position_order: int = 3
    attitude_order: int = 5
    attitude_wobble_rad: float = 5e-6
    rpc_grid: tuple[int, int, int] = (21, 21, 7)
    terrain_wavelengths_m: tuple[float, float] = (4000.0, 40000.0)
    centre_columns: bool = False

    def __post_init__(self):
        sc.require(self.site in SITES, "site", f"be one of {sorted(SITES)}", self.site)
        for name in ("centre_lon_deg", "centre_lat_deg"):
            if getattr(self, name) is not None:
                sc.check_finite(self, name)
        if self.h_range_m is not None:
            sc.check_range(self, "h_range_m")
        if self.n_points is not None:
            sc.check_int(self, "n_points", 1)
        layouts = (None, "quarter", "grid")
        sc.require(self.layout in layouts, "layout", "be 'quarter' or 'grid'", self.layout)
        sc.check_int(self, "n_gcps", 0)
        points = self.n_points if self.n_points is not None else SITES[self.site]["n_points"]
        sc.require(self.n_gcps <= points, "n_gcps", f"be at most the site's {points} points",
                   self.n_gcps)  # fmt: skip
        sc.check_non_negative(self, "image_noise_px", "ground_noise_m", "attitude_wobble_rad")
        sc.check_positive(self, "image_sigma_px", "ground_sigma_m", "altitude_m",
                          "focal_length_m", "pixel_size_m", "line_time_s")  # fmt: skip
        sc.require(isinstance(self.vendor_errors, sc.VendorErrors), "vendor_errors",
                 "be a VendorErrors", self.vendor_errors)  # fmt: skip
        sc.check_numbers(self, "view_angles_deg", 2)
        for name in ("n_rows", "n_cols"):
            sc.check_int(self, name, 2)
        sc.check_epoch(self, "epoch_utc")
        for name in ("position_order", "attitude_order"):
            sc.check_int(self, name, 0)
        sc.check_rpc_grid(self)
        sc.check_range(self, "terrain_wavelengths_m", positive=True)
        sc.require(isinstance(self.centre_columns, bool), "centre_columns", "be True or False",
                 self.centre_columns)  # fmt: skip


def cartosat1_stereo(seed: int = 0, settings: Cartosat1Settings | None = None) -> StereoScene:
    """Simulate a Cartosat-1 stereo pair (see the module docstring) with ``settings``
    (:class:`Cartosat1Settings`, default: the Hobart pair of 000_), deterministic in ``seed``.
    Returns a :class:`StereoScene`."""
    sc.check_int_value(seed, "seed", 0)
    s = Cartosat1Settings() if settings is None else settings
    preset = SITES[s.site]
    lon = preset["lon"] if s.centre_lon_deg is None else float(s.centre_lon_deg)
    lat = preset["lat"] if s.centre_lat_deg is None else float(s.centre_lat_deg)
    h_range = tuple(preset["h_range"] if s.h_range_m is None else s.h_range_m)
    n_points = int(preset["n_points"] if s.n_points is None else s.n_points)
    layout = preset["layout"] if s.layout is None else s.layout
    # truth.json's params: the settings as resolved for the site, the vendor errors last
    params = {"seed": seed}
    params |= {f.name: getattr(s, f.name) for f in dataclasses.fields(s)}
    params |= dict(centre_lon_deg=lon, centre_lat_deg=lat, h_range_m=h_range, n_points=n_points,
                   layout=layout)  # fmt: skip
    params.pop("vendor_errors")
    # (the names a former version left out of its parameters: kept, so that the same settings
    # still write the same bytes, the packaged demo's truth.json included)
    params["skip"] = ["preset", "vendor_errors", "lon", "lat", "h_range"]
    params["vendor_errors"] = s.vendor_errors.to_dict()
    # recorded only when set (the packaged demo's truth.json predates these options)
    if tuple(s.terrain_wavelengths_m) == (4000.0, 40000.0):
        params.pop("terrain_wavelengths_m")
    if not s.centre_columns:
        params.pop("centre_columns")
    rng = np.random.default_rng(seed)

    # --- the pass: orbit over the site, then the scan times of the two images
    theta0 = gmst_rad(s.epoch_utc)
    orbit = CircularOrbit.over(
        lon, lat, s.altitude_m, sun_synchronous_inclination_deg(s.altitude_m), theta0
    )
    h_mid = 0.5 * (h_range[0] + h_range[1])
    target = np.array([lon, lat, h_mid])
    v_ground = orbit.mean_motion_rad_s * geodesy.WGS84_A_M  # sub-satellite speed (m/s)
    duration = (s.n_rows - 1) * s.line_time_s
    camera = EphemerisSettings(
        sidereal_angle_rad=theta0, line_time_s=s.line_time_s, n_rows=s.n_rows, n_cols=s.n_cols,
        focal_length_m=s.focal_length_m, pixel_size_m=s.pixel_size_m,
        position_order=s.position_order, attitude_order=s.attitude_order, h_ref_m=h_mid,
    )  # fmt: skip
    times = []
    for angle in s.view_angles_deg:  # a rough time, then the exact one from a provisional model
        t = -s.altitude_m * math.tan(math.radians(angle)) / v_ground
        model = ephemeris_from_orbit(
            orbit, (t - 60, t + 60), camera, first_line_time_s=t - duration / 2,
            view_angles_deg=(angle, 0.0, 0.0),
        )  # fmt: skip
        times.append(_centre_time(model, target))
    span = (min(times) - duration, max(times) + duration)
    n_att = min(s.attitude_order, 3) + 1
    wobble = rng.normal(0.0, s.attitude_wobble_rad, (3, n_att)) / np.arange(1, n_att + 1)
    truth = {}
    for name, angle, t in zip(NAMES, s.view_angles_deg, times, strict=False):
        model = ephemeris_from_orbit(
            orbit, span, camera, first_line_time_s=t - duration / 2,
            view_angles_deg=(angle, 0.0, 0.0), attitude_offsets_rad=wobble,
        )  # fmt: skip
        if s.centre_columns:
            col = float(np.asarray(sc.project(model, target))[0])
            shift = 0.5 * (s.n_cols - 1) - col  # columns are linear in the principal column
            model = eqx.tree_at(lambda m: m.principal_col_px, model, model.principal_col_px + shift)
        truth[name] = sc.quantize_model(model)

    # --- terrain over both footprints, and the GPS point field
    c, r = s.n_cols - 1, s.n_rows - 1
    corners = np.array([[0, 0], [c, 0], [0, r], [c, r]], float)
    foot = [np.asarray(sc.localize(m, corners, h_mid)) for m in truth.values()]
    terrain = Terrain.random(
        rng, np.concatenate(foot)[:, :2], h_range, wavelength_range_m=s.terrain_wavelengths_m
    )
    fore, aft = truth["fore"], truth["aft"]
    aft_in_fore = np.asarray(sc.project(fore, foot[1]))
    margin = min(200.0, min(s.n_rows, s.n_cols) / 8.0)  # 200 px, less in small images
    lo = np.maximum(aft_in_fore.min(0), 0.0) + margin
    hi = np.minimum(aft_in_fore.max(0), [s.n_cols - 1, s.n_rows - 1]) - margin
    if layout == "quarter":
        hi = 0.5 * (lo + hi)
        cand = lo + (hi - lo) * rng.uniform(0.0, 1.0, (4 * n_points, 2))
    else:
        side = math.ceil(math.sqrt(n_points))
        cells = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)
        jitter = rng.uniform(0.15, 0.85, (4, len(cells), 2))
        cand = (lo + (hi - lo) * (cells + jitter) / side).reshape(-1, 2)
    ground_all = sc.points_on_terrain(fore, cand, terrain)
    img_fore = np.asarray(sc.project(fore, ground_all))
    img_aft = np.asarray(sc.project(aft, ground_all))
    size = np.array([s.n_cols - 1, s.n_rows - 1])
    m = margin / 4.0
    inside = np.all(
        (img_fore > m) & (img_fore < size - m) & (img_aft > m) & (img_aft < size - m), -1
    )
    keep = np.flatnonzero(inside)[:n_points]
    if len(keep) < n_points:
        raise ValueError(f"could only place {len(keep)} of {n_points} points in both images")
    ground_true = ground_all[keep]
    ids = tuple(f"P{i + 1:03d}" for i in range(n_points))
    gcp = set(sc.spread_selection(img_fore[keep], s.n_gcps).tolist())
    roles = tuple("gcp" if i in gcp else "check" for i in range(n_points))
    surveyed = sc.ground_noise(rng, ground_true, s.ground_noise_m)
    ground = GroundPoints(ids, surveyed, roles, np.full((n_points, 3), float(s.ground_sigma_m)))

    # --- image measurements (true + noise), per image then per point
    true_xy = [sc.quantize_image(sc.project(truth[n], ground_true)) for n in NAMES]
    noisy_xy = [
        sc.quantize_image(xy + rng.normal(0.0, s.image_noise_px, xy.shape)) for xy in true_xy
    ]
    pids = tuple(p for _ in NAMES for p in ids)
    images = tuple(n for n in NAMES for _ in ids)
    image_true = Observations(pids, images, np.concatenate(true_xy), np.zeros(2 * n_points))
    observations = Observations(
        pids, images, np.concatenate(noisy_xy), np.full(2 * n_points, float(s.image_sigma_px))
    )

    # --- the vendor's orientation and its RPCs
    d_att, d_pos = sc.draw_common_errors(rng, s.vendor_errors, fore)
    d_view = sc.draw_mount_errors(rng, s.vendor_errors, fore, len(NAMES))
    vendor_models = {
        n: sc.quantize_model(sc.perturb(truth[n], d_att, d_pos, d_view[i]))
        for i, n in enumerate(NAMES)
    }
    pad = 0.1 * (h_range[1] - h_range[0]) + 50.0
    fits = fit_rpcs(
        [vendor_models[n] for n in NAMES],
        h_range=(h_range[0] - pad, h_range[1] + pad),
        grid=s.rpc_grid,
    )
    vendor = {n: sc.quantize_model(rpc) for n, (rpc, _) in zip(NAMES, fits, strict=False)}
    reports = {n: rep for n, (_, rep) in zip(NAMES, fits, strict=False)}
    return StereoScene(
        NAMES, truth, vendor_models, vendor, reports, ground, ground_true, observations,
        image_true, terrain, sc.rounded(params, 12),
    )  # fmt: skip


def write_cartosat1_stereo(
    directory: str | os.PathLike,
    seed: int = 0,
    settings: Cartosat1Settings | None = None,
    *,
    overwrite: bool = False,
) -> StereoScene:
    """Simulate a pair (:func:`cartosat1_stereo`) and write it into ``directory``
    (:meth:`StereoScene.save`: files ready for ``jaxgeo adjust``); existing files are refused
    before any work unless ``overwrite``. Returns the scene."""
    sc.check_writable(stereo_output_files(directory), overwrite)
    scene = cartosat1_stereo(seed, settings)
    scene.save(directory, overwrite=overwrite)
    return scene
