"""Simulated Carto-2S full strips cut into sub-scenes (003_a7d3ea260371d8c5.txt, sections 8-11).

One continuous rigorous model (:class:`~jaxgeo.models.EphemerisModel`, position order 5 and
attitude order 9 over the whole pass) images a long strip; sub-scenes of about 31 km (along track)
x 15 km are cut from it by line offsets, adjacent ones overlapping by ``overlap_rows`` lines. Sub-
scene ``k`` starts at strip line ``first_rows[k] = k * (scene_rows - overlap_rows)``: its row
``r`` is strip line ``first_rows[k] + r``, seen by the same ray, so a point in the overlap of two
sub-scenes is imaged (and can be localised) in both -- the tie points of 003_ section 8 come
from these known offsets.

Each sub-scene has its own "vendor" RPC, fitted to the strip model perturbed by errors common to
the pass (pointing bias and drift, ephemeris offset) plus a per-scene pointing error, hence the
discontinuities between scenes that the full-strip adjustment removes. Ground points are
surveyed in every scene (``check``) and, as control, only in every ``gcp_every``-th scene and the
last one (003_ section 9).

The RMS error of a sub-scene's vendor RPC on its true points (:meth:`StripScene.accuracy`) lies
in :data:`VENDOR_RMS_RANGE_PX` (1-100 px) for strips of 20 to 320 sub-scenes: the common pitch
(18-30 px) and roll (10 px) dominate, and the drift (0.03 px/s) grows with the strip's duration
(~1.4 min at 20 sub-scenes, ~22 min at 320). Measured with seeds 0-2 (min-max over sub-scenes):
80 sub-scenes 11-41 px, 100: 13-31, 160: 17-44, 320: 3.5-75. (Until the measurements were
projected through each sub-scene's own model, strips of 100 or more sub-scenes gave 1e4-1e8 px:
the strip model's Newton in scan time diverges more than ~200 s from its centre line.)
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

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

STRIP_ERRORS = sc.VendorErrors(
    pitch_px=(18.0, 30.0),
    roll_px=10.0,
    yaw_rad=2e-5,
    mount_along_px=2.0,
    mount_across_px=2.0,
    drift_px_per_s=0.03,
    position_m=(4.0, 3.0, 3.0),
)
"""Vendor errors of a strip: ~13-19 m direct-ortho errors (003_, table 1); the ``mount_*`` terms are
the per-scene pointing errors."""

VENDOR_RMS_RANGE_PX = (1.0, 100.0)
"""Documented range of each sub-scene's vendor-RPC RMS error (px) for 20-320 sub-scenes."""


def scene_names(n_scenes: int) -> tuple[str, ...]:
    """``scene_000``, ``scene_001``, ... (more digits past 1000 scenes)."""
    width = max(3, len(str(n_scenes - 1)))
    return tuple(f"scene_{k:0{width}d}" for k in range(n_scenes))


def strip_output_files(directory: str | os.PathLike, n_scenes: int) -> list[pathlib.Path]:
    """The files :meth:`StripScene.save` writes for ``n_scenes`` sub-scenes."""
    d = pathlib.Path(directory)
    names = ["ground.csv", "observations.csv", "strip.json", "truth.json"]
    return [d / f"{n}.txt" for n in scene_names(n_scenes)] + [d / n for n in names]


@eqx.filter_jit
def _project_chunk_from(model: EphemerisModel, first_line_s, n_rows: int, ground):
    def one(t_first, g):
        return dataclasses.replace(model, first_line_time_s=t_first, n_rows=n_rows).project(g)

    return jax.vmap(one)(first_line_s, ground)


def _project_from_lines(model, first_line_s, n_rows: int, ground, chunk: int = 512) -> np.ndarray:
    """``(n, 2)`` projections of ``ground`` ``(n, 3)``, point ``i`` through ``model`` cut to
    ``n_rows`` lines from scan time ``first_line_s[i]`` (image rows relative to that cut)."""
    n = len(ground)
    n_pad = -(-max(n, 1) // chunk) * chunk
    t = np.pad(np.asarray(first_line_s, float), (0, n_pad - n), mode="edge")
    g = np.pad(np.asarray(ground, float), [(0, n_pad - n), (0, 0)], mode="edge")
    out = [
        np.asarray(_project_chunk_from(model, jnp.asarray(t[i : i + chunk]), n_rows,
                                       jnp.asarray(g[i : i + chunk])))
        for i in range(0, n_pad, chunk)
    ]  # fmt: skip
    return np.concatenate(out)[:n]


@dataclasses.dataclass(frozen=True)
class StripScene:
    """A simulated strip: the strip truth, per-scene vendor RPCs, ground points, measurements.

    Sub-scene ``k`` (``names[k]``) covers strip lines ``first_rows[k] .. first_rows[k] +
    scene_rows - 1``. ``ground`` holds surveyed (noisy) coordinates with roles; ``ground_true`` the
    true ones (same order); ``image_true`` the exact projections (same rows as ``observations``).
    """

    names: tuple[str, ...]
    first_rows: np.ndarray
    scene_rows: int
    n_cols: int
    truth_strip: EphemerisModel
    vendor_strip: EphemerisModel
    vendor_scene_errors_rad: np.ndarray
    vendor: dict[str, RPC]
    fit_reports: dict[str, RPCFitReport]
    ground: GroundPoints
    ground_true: np.ndarray
    observations: Observations
    image_true: Observations
    terrain: Terrain
    params: dict

    def truth_model(self, k: int) -> EphemerisModel:
        """The rigorous model of sub-scene ``k`` (the strip model cut at its line offset)."""
        return sc.quantize_model(
            self.truth_strip.with_rows(int(self.first_rows[k]), self.scene_rows)
        )

    def vendor_model(self, k: int) -> EphemerisModel:
        """The perturbed model the vendor RPC of sub-scene ``k`` was fitted to."""
        cut = self.vendor_strip.with_rows(int(self.first_rows[k]), self.scene_rows)
        return sc.quantize_model(
            dataclasses.replace(
                cut, view_angles_rad=cut.view_angles_rad + self.vendor_scene_errors_rad[k]
            )
        )

    def accuracy(self) -> dict:
        """Direct georeferencing error (px) of each scene's vendor RPC on its true points."""
        index = {pid: i for i, pid in enumerate(self.ground.ids)}
        per_scene = {}
        for name in self.names:
            rows = [i for i, img in enumerate(self.image_true.images) if img == name]
            if not rows or name not in self.vendor:
                continue
            g = self.ground_true[[index[self.image_true.point_ids[i]] for i in rows]]
            res = sc.project(self.vendor[name], g) - self.image_true.xy[rows]
            rx, ry = sc.rms(res)
            per_scene[name] = {"rms_x": rx, "rms_y": ry, "rms": math.hypot(rx, ry)}
        all_rms = [v["rms"] for v in per_scene.values()]
        return sc.rounded({"image_px": per_scene, "rms_min": min(all_rms), "rms_max": max(all_rms)})

    def files(self, directory: str | os.PathLike) -> list[pathlib.Path]:
        return strip_output_files(directory, len(self.names))

    def strip_json(self) -> dict:
        return {
            "mission": "Carto-2S (simulated by jaxgeo.simulate.carto2s_strip)",
            "n_scenes": len(self.names),
            "scene_rows": self.scene_rows,
            "n_cols": self.n_cols,
            "overlap_rows": int(self.params["overlap_rows"]),
            "strip_rows": int(self.truth_strip.n_rows),
            "scenes": [
                {
                    "name": n,
                    "rpc": f"{n}.txt",
                    "first_line": int(self.first_rows[k]),
                    "n_rows": self.scene_rows,
                    "n_cols": self.n_cols,
                    "has_gcps": any(
                        r == "gcp" and pid.startswith(n + "_")
                        for pid, r in zip(self.ground.ids, self.ground.role, strict=False)
                    ),
                }
                for k, n in enumerate(self.names)
            ],
        }

    def truth_json(self) -> dict:
        return {
            "generator": "jaxgeo.simulate.carto2s_strip",
            "params": self.params,
            "first_rows": self.first_rows.tolist(),
            "truth_strip_model": self.truth_strip.to_dict(),
            "vendor_strip_model": self.vendor_strip.to_dict(),
            "vendor_scene_view_errors_rad": self.vendor_scene_errors_rad.tolist(),
            "rpc_fit": {n: sc.rounded(r.to_dict(), 9) for n, r in self.fit_reports.items()},
            **sc.truth_tail(self),
        }

    def save(self, directory: str | os.PathLike, overwrite: bool = False) -> list[pathlib.Path]:
        """Write ``scene_000.txt`` ... (RPC text), ``ground.csv``, ``observations.csv``,
        ``strip.json`` (each sub-scene's name, RPC file, first strip line, size) and
        ``truth.json``; refuses to replace existing files unless ``overwrite``."""
        from ..io import write_rpc_text

        missing = [n for n in self.names if n not in self.vendor]
        if missing:
            raise ValueError(
                f"{len(missing)} sub-scene(s) have no vendor RPC (simulated with rpc_scenes): "
                "nothing written"
            )
        paths = self.files(directory)
        sc.check_writable(paths, overwrite)
        pathlib.Path(directory).mkdir(parents=True, exist_ok=True)
        for name, path in zip(self.names, paths, strict=False):
            write_rpc_text(self.vendor[name], path, overwrite=overwrite)
        write_ground(self.ground, paths[-4], overwrite=overwrite)
        write_observations(self.observations, paths[-3], overwrite=overwrite)
        sc.write_json(paths[-2], self.strip_json(), overwrite)
        sc.write_json(paths[-1], self.truth_json(), overwrite)
        return paths


@dataclasses.dataclass(frozen=True)
class Carto2SStripSettings:
    """The options of :func:`carto2s_strip` (a Carto-2S strip; module docstring).

    The site (``centre_lon_deg``, ``centre_lat_deg``, terrain heights ``h_range_m``); the
    mission (``altitude_m``, ``focal_length_m``, ``pixel_size_m``, ``line_time_s``: default
    square ground pixels at nadir), the sub-scenes (``n_cols`` x ``scene_rows`` px, adjacent ones
    overlapping by ``overlap_rows`` lines: with the defaults ~30 km x 15 km of 0.63 m pixels);
    the points: sub-scenes ``0, gcp_every, 2 gcp_every, ...`` and the last carry
    ``gcps_per_scene`` GCPs, every one ``checks_per_scene`` check points; measurement noise and
    a-priori sigmas (``image_*_px``, ``ground_*_m``); the vendor's errors
    (:class:`VendorErrors`), the pass's ``epoch_utc``, the truth's polynomial orders and
    attitude wobble, the vendor's RPC fit grid (columns, rows, heights). ``rpc_scenes`` fits
    vendor RPCs for those sub-scenes only (a quick look at a long strip; such a strip cannot be
    saved). Checked when made: a bad value raises :class:`SimulationError` naming the field.
    """

    centre_lon_deg: float = 74.5
    centre_lat_deg: float = 27.0
    h_range_m: tuple[float, float] = (100.0, 1500.0)
    altitude_m: float = 505e3
    focal_length_m: float = 5.6
    pixel_size_m: float = 7e-6
    line_time_s: float | None = None
    n_cols: int = 24000
    scene_rows: int = 48000
    overlap_rows: int = 1500
    gcp_every: int = 4
    gcps_per_scene: int = 4
    checks_per_scene: int = 2
    image_noise_px: float = 0.3
    image_sigma_px: float = 0.5
    ground_noise_m: float = 0.1
    ground_sigma_m: float = 0.3
    vendor_errors: sc.VendorErrors = STRIP_ERRORS
    epoch_utc: str = "2017-10-12T05:30:00Z"
    position_order: int = 5
    attitude_order: int = 9
    attitude_wobble_rad: float = 5e-6
    rpc_grid: tuple[int, int, int] = (21, 21, 7)
    rpc_scenes: tuple[int, ...] | None = None

    def __post_init__(self):
        sc.check_finite(self, "centre_lon_deg", "centre_lat_deg")
        sc.check_range(self, "h_range_m")
        sc.check_positive(self, "altitude_m", "focal_length_m", "pixel_size_m",
                          "image_sigma_px", "ground_sigma_m")  # fmt: skip
        if self.line_time_s is not None:
            sc.check_positive(self, "line_time_s")
        for name, low in (("n_cols", 2), ("scene_rows", 2), ("overlap_rows", 0),
                          ("gcp_every", 1), ("gcps_per_scene", 0), ("checks_per_scene", 0),
                          ("position_order", 0), ("attitude_order", 0)):  # fmt: skip
            sc.check_int(self, name, low)
        sc.require(self.overlap_rows < self.scene_rows, "overlap_rows",
                 f"be in [0, scene_rows = {self.scene_rows})", self.overlap_rows)  # fmt: skip
        sc.check_non_negative(self, "image_noise_px", "ground_noise_m", "attitude_wobble_rad")
        sc.require(isinstance(self.vendor_errors, sc.VendorErrors), "vendor_errors",
                 "be a VendorErrors", self.vendor_errors)  # fmt: skip
        sc.check_epoch(self, "epoch_utc")
        sc.check_rpc_grid(self)
        if self.rpc_scenes is not None:
            ok = all(sc.is_int(k) and k >= 0 for k in self.rpc_scenes)
            sc.require(ok, "rpc_scenes", "be sub-scene indices (integers >= 0)", self.rpc_scenes)


def carto2s_strip(
    n_scenes: int = 80, seed: int = 0, settings: Carto2SStripSettings | None = None
) -> StripScene:
    """Simulate a Carto-2S strip of ``n_scenes`` sub-scenes (see the module docstring) with
    ``settings`` (:class:`Carto2SStripSettings`), deterministic in ``seed``. Returns a
    :class:`StripScene`."""
    sc.check_int_value(n_scenes, "n_scenes", 1)
    sc.check_int_value(seed, "seed", 0)
    n_scenes = int(n_scenes)
    s = Carto2SStripSettings() if settings is None else settings
    params = {"n_scenes": n_scenes, "seed": seed}
    params |= {f.name: getattr(s, f.name) for f in dataclasses.fields(s)}
    params.pop("vendor_errors")  # (last in truth.json)
    params["vendor_errors"] = s.vendor_errors.to_dict()
    fitted = range(n_scenes) if s.rpc_scenes is None else sorted({int(k) for k in s.rpc_scenes})
    if any(not 0 <= k < n_scenes for k in fitted):
        raise sc.SimulationError(
            f"{{}} must lie in [0, n_scenes = {n_scenes}), got {s.rpc_scenes}", "rpc_scenes"
        )
    rng = np.random.default_rng(seed)

    theta0 = gmst_rad(s.epoch_utc)
    orbit = CircularOrbit.over(
        s.centre_lon_deg,
        s.centre_lat_deg,
        s.altitude_m,
        sun_synchronous_inclination_deg(s.altitude_m),
        theta0,
    )
    line_time_s = s.line_time_s
    if line_time_s is None:
        gsd = s.altitude_m * s.pixel_size_m / s.focal_length_m
        line_time_s = gsd / (orbit.mean_motion_rad_s * (orbit.radius_m - s.altitude_m))
    params["line_time_s"] = line_time_s
    step = s.scene_rows - s.overlap_rows
    first_rows = np.arange(n_scenes) * step
    strip_rows = int(first_rows[-1] + s.scene_rows)
    t_start = -0.5 * (strip_rows - 1) * line_time_s
    t_end = -t_start
    h_mid = 0.5 * (s.h_range_m[0] + s.h_range_m[1])
    n_att = min(s.attitude_order, 3) + 1
    wobble = rng.normal(0.0, s.attitude_wobble_rad, (3, n_att)) / np.arange(1, n_att + 1)
    camera = EphemerisSettings(
        sidereal_angle_rad=theta0, line_time_s=line_time_s, n_rows=strip_rows, n_cols=s.n_cols,
        focal_length_m=s.focal_length_m, pixel_size_m=s.pixel_size_m,
        position_order=s.position_order, attitude_order=s.attitude_order, h_ref_m=h_mid,
    )  # fmt: skip
    strip = ephemeris_from_orbit(
        orbit,
        (t_start - 2.0, t_end + 2.0),
        camera,
        first_line_time_s=t_start,
        attitude_offsets_rad=wobble,
    )
    strip = sc.quantize_model(strip)
    names = scene_names(n_scenes)

    # --- terrain over the strip and the surveyed points, scene by scene
    corners = np.array(
        [[0, 0], [s.n_cols - 1, 0], [0, strip_rows - 1], [s.n_cols - 1, strip_rows - 1]], float
    )
    foot = sc.localize(strip, corners, h_mid)
    terrain = Terrain.random(rng, foot[:, :2], s.h_range_m, fit_relief=False)
    has_gcps = [(k % s.gcp_every == 0) or (k == n_scenes - 1) for k in range(n_scenes)]
    ids, roles, cand = [], [], []
    margin = 100.0
    for k, name in enumerate(names):
        n_gcp = s.gcps_per_scene if has_gcps[k] else 0
        n = n_gcp + s.checks_per_scene
        u = rng.uniform(0.0, 1.0, (n, 2))
        col = margin + u[:, 0] * (s.n_cols - 1 - 2 * margin)
        row = first_rows[k] + margin + u[:, 1] * (s.scene_rows - 1 - 2 * margin)
        cand.append(np.stack([col, row], -1))
        ids += [f"{name}_{'G' if i < n_gcp else 'C'}{i + 1:02d}" for i in range(n)]
        roles += ["gcp" if i < n_gcp else "check" for i in range(n)]
    ground_true = sc.points_on_terrain(strip, np.concatenate(cand), terrain)
    n_pts = len(ids)
    surveyed = sc.ground_noise(rng, ground_true, s.ground_noise_m)
    ground = GroundPoints(
        tuple(ids), surveyed, tuple(roles), np.full((n_pts, 3), float(s.ground_sigma_m))
    )

    # --- measurements: every sub-scene whose lines contain the point, projected through that
    # sub-scene's own model, whose Newton in scan time starts at that sub-scene's centre line. Not
    # through the strip model: its Newton starts at the strip's centre line and, more than ~200 s
    # (about 90 sub-scenes) away, no longer converges on the curved orbit (100-320 scenes gave
    # truth coordinates wrong by 1e4-1e8 px, hence vendor RPCs "wrong" by as much).
    home = np.concatenate(cand)[:, 1] // step  # the sub-scene each point was made in
    home = np.minimum(home.astype(int), n_scenes - 1)
    cut_first_s = sc.round_sig(strip.row_time(jnp.asarray(first_rows[home], float)))  # truth_model
    xy_home = _project_from_lines(sc.quantize_model(strip), cut_first_s, s.scene_rows, ground_true)
    strip_xy = xy_home + np.stack([np.zeros(n_pts), first_rows[home]], -1)
    obs_pid, obs_img, obs_xy = [], [], []
    for i in range(n_pts):
        col, row = strip_xy[i]
        for k in np.flatnonzero((first_rows <= row) & (row <= first_rows + s.scene_rows - 1)):
            if 0.0 <= col <= s.n_cols - 1:
                obs_pid.append(ids[i])
                obs_img.append(names[k])
                obs_xy.append((col, row - first_rows[k]))
    true_xy = sc.quantize_image(np.asarray(obs_xy, float).reshape(-1, 2))
    noisy_xy = sc.quantize_image(true_xy + rng.normal(0.0, s.image_noise_px, true_xy.shape))
    m = len(obs_pid)
    image_true = Observations(tuple(obs_pid), tuple(obs_img), true_xy, np.zeros(m))
    observations = Observations(
        tuple(obs_pid), tuple(obs_img), noisy_xy, np.full(m, float(s.image_sigma_px))
    )

    # --- vendor: common pass errors + per-scene pointing errors, one RPC per sub-scene
    d_att, d_pos = sc.draw_common_errors(rng, s.vendor_errors, strip)
    vendor_strip = sc.quantize_model(sc.perturb(strip, d_att, d_pos, np.zeros(3)))
    scene_err = sc.round_sig(sc.draw_mount_errors(rng, s.vendor_errors, strip, n_scenes))
    partial = StripScene(
        names, first_rows, int(s.scene_rows), int(s.n_cols), strip, vendor_strip, scene_err, {},
        {}, ground, ground_true, observations, image_true, terrain, sc.rounded(params, 12),
    )  # fmt: skip
    pad = 0.1 * (s.h_range_m[1] - s.h_range_m[0]) + 50.0
    names_fitted = [names[k] for k in fitted]
    fits = fit_rpcs(
        [partial.vendor_model(k) for k in fitted],
        h_range=(s.h_range_m[0] - pad, s.h_range_m[1] + pad),
        grid=s.rpc_grid,
    )
    vendor = {n: sc.quantize_model(rpc) for n, (rpc, _) in zip(names_fitted, fits, strict=True)}
    reports = {n: rep for n, (_, rep) in zip(names_fitted, fits, strict=True)}
    return dataclasses.replace(partial, vendor=vendor, fit_reports=reports)


def write_carto2s_strip(
    directory: str | os.PathLike,
    n_scenes: int = 80,
    seed: int = 0,
    settings: Carto2SStripSettings | None = None,
    *,
    overwrite: bool = False,
) -> StripScene:
    """Simulate a strip (:func:`carto2s_strip`) and write it into ``directory``
    (:meth:`StripScene.save`: files ready for ``jaxgeo adjust`` and ``jaxgeo strip``); existing
    files are refused before any work unless ``overwrite``. Returns the strip."""
    sc.check_int_value(n_scenes, "n_scenes", 1)
    sc.check_writable(strip_output_files(directory, n_scenes), overwrite)
    strip = carto2s_strip(n_scenes, seed, settings)
    strip.save(directory, overwrite=overwrite)
    return strip
