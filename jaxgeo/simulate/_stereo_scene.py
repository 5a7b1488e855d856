"""Scene-size simulated truth: a Pleiades-like pushbroom stereo pair rendered through its true
physical models over a textured synthetic terrain, streamed to disk block by block.

:func:`stereo_scene` (``jaxgeo simulate stereo-scene``) writes into a folder:

``left.tif``, ``right.tif``
    The images, ``size`` x ``size`` px, uint16 (12-bit values, 0..4095), tiled 256 x 256,
    DEFLATE; no geotransform: each carries its vendor RPC in the GeoTIFF RPC tag
    (RPCCoefficientTag, read by GDAL and :func:`jaxgeo.io.read_rpc`), RPC00B, image coordinates
    in jaxgeo's convention (GDAL's pixel/line = ours + 0.5). ``left`` looks forward along track,
    ``right`` backward (base/height about 0.45), GSD about 0.67 m.
``truth_dsm.tif``
    The true surface: the terrain's ellipsoidal height (WGS84, m) at the centres of a north-up
    grid in the local UTM zone, cells of about the GSD (the GSD rounded to 5 cm), float32, NaN
    (the nodata value) outside the area both images see (their footprints on the terrain, to
    within a cell), tiled, DEFLATE.
``truth.json``
    What rebuilds everything (:func:`read_stereo_scene`): ``params`` (the options), per image
    ``images.<name>``: ``true_model`` (the jitter-free :class:`~jaxgeo.models.EphemerisModel`,
    ``EphemerisModel.from_dict``), ``jitter`` (``amplitude_px`` x/y, ``period_lines``,
    ``phase_rad`` x/y in the image's own rows, see :class:`JitteredModel`; amplitude zero: no
    jitter), ``vendor_model`` (the perturbed copy the RPC was fitted to), ``rpc_fit`` (the fit's
    residuals against ``vendor_model`` on the fit and check grids, px), ``rpc_vs_truth`` (the
    delivered RPC minus the jitter-free (``nojitter_px``) and the jittered (``jittered_px``)
    true model at the truth points: ``mean_xy``, ``rms``, ``max``, px) and ``gain``;
    ``terrain`` (:class:`~jaxgeo.simulate.Terrain`), ``texture`` (:class:`ProceduralTexture`),
    ``render`` (:class:`RenderSettings`), ``gsd_m``, ``base_to_height``, ``dsm`` (``epsg``,
    upper-left corner ``x0, y0``, ``res_m``, ``rows, cols``) and ``points``: a grid of true
    ground points (on the terrain, seen by both images), ``lonlath`` with their true image
    coordinates ``xy`` (through the jittered models, as rendered; jaxgeo's pixel convention)
    and ``xy_nojitter`` (through the jitter-free ones).

The RPCs are fitted without the jitter (a vendor's smooth attitude cannot hold it), by default to
a copy of the truth with small pointing and ephemeris errors (a few pixels of bias, as delivered
RPCs have; ``PLEIADES_ERRORS`` of :mod:`._stereo_scene_models`), or exactly
(``exact_rpc=True``: the RPCs then reproject truth points to the true jitter-free pixel to
~1e-5 px, the fit's 1e-7 px plus the rounding of the coefficients to 12 digits). Memory is
bounded by the window size, whatever the image size (images and DSM are written in windows
of 256 x 1024 px, GDAL's block cache held at 64 MB); everything is deterministic in the seed
(bit-identical files on one machine).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import pathlib
import warnings

import numpy as np

from .._runtime.progress import Progress
from ..geodesy import utm_epsg, utm_zone
from ..io import to_rasterio_rpc
from ..io.internal import atomic_output, raster_writer
from ..models import RPC, AbstractSensorModel, EphemerisModel
from . import _scene as sc
from ._render import terrain_bracket
from ._scene import SimulationError
from ._stereo_scene_models import (
    JITTER_ALONG_RATIO,
    NAMES,
    PleiadesSettings,
    base_to_height,
    draw_ground,
    jitter_phases,
    localize_on_terrain_exact,
    pixel_size_on_ground_m,
    pleiades_pair,
    project_true,
    true_models,
    vendor_rpcs,
)
from ._stereo_scene_render import (
    RenderedImage,
    RenderSettings,
    image_profile,
    render_window,
    scene_windows,
    write_blocks,
)
from ._stereo_scene_texture import ProceduralTexture
from ._terrain import Terrain, TerrainChange

FILES = ("left.tif", "right.tif", "truth_dsm.tif", "truth.json")
SITE = (5.27, 44.17, 300.0)
"""Centre lon, lat (deg) and lowest terrain height (m, ellipsoidal) of the simulated site."""
GAINS = {"left": 1.0, "right": 0.97}
GDAL_CACHE_MB = 64
"""GDAL's block cache while writing (MB)."""
N_POINTS_SIDE = 15
"""The truth points: a 15 x 15 grid over the left image, kept where the right image sees them."""


def stereo_scene_files(directory: str | os.PathLike) -> list[pathlib.Path]:
    """The files :func:`stereo_scene` writes in ``directory``."""
    return [pathlib.Path(directory) / f for f in FILES]


def default_relief_m(size: int, gsd_m: float = 0.67) -> float:
    """The default terrain relief (m): a tenth of the footprint, 30..300 m."""
    return float(min(max(0.1 * size * gsd_m, 30.0), 300.0))


@dataclasses.dataclass(frozen=True)
class DSMSpec:
    """The truth DSM's grid: ``epsg`` (UTM), upper-left corner ``x0, y0`` (m), ``res_m``,
    ``rows, cols``."""

    epsg: int
    x0: float
    y0: float
    res_m: float
    rows: int
    cols: int

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class StereoSceneTruth:
    """Everything about a simulated stereo scene (module docstring): ``base`` the jitter-free
    true models, ``truth`` the models the images are rendered with (``base`` wrapped in a
    :class:`JitteredModel` when there is jitter), ``vendor`` the models the RPCs were fitted to,
    ``rpcs`` the delivered RPCs, ``points`` ``(n, 3)`` true ground points with ``xy[name]`` their
    true image coordinates ``(n, 2)``, ``info`` the rest of ``truth.json`` (params, phases,
    fit reports, accuracy, GSD, base/height)."""

    base: dict[str, EphemerisModel]
    truth: dict[str, AbstractSensorModel]
    vendor: dict[str, EphemerisModel]
    rpcs: dict[str, RPC]
    terrain: Terrain
    texture: ProceduralTexture
    render: RenderSettings
    dsm: DSMSpec
    points: np.ndarray
    xy: dict[str, np.ndarray]
    info: dict

    @property
    def size(self) -> int:
        return int(self.info["params"]["size"])

    def to_json(self) -> dict:
        """``truth.json`` (module docstring)."""
        images = {}
        for n in NAMES:
            images[n] = {
                "file": f"{n}.tif",
                "true_model": self.base[n].to_dict(),
                "jitter": self.info["jitter"][n],
                "vendor_model": self.vendor[n].to_dict(),
                "rpc_fit": self.info["rpc_fit"][n],
                "rpc_vs_truth": self.info["rpc_vs_truth"][n],
                "gain": GAINS[n],
            }
        return {
            "generator": "jaxgeo.simulate.stereo_scene",
            "params": self.info["params"],
            "images": images,
            "terrain": self.terrain.to_dict(),
            "texture": self.texture.to_dict(),
            "render": self.render.to_dict(),
            "gsd_m": self.info["gsd_m"],
            "base_to_height": self.info["base_to_height"],
            "dsm": {"file": "truth_dsm.tif", **self.dsm.to_dict()},
            "points": {
                "lonlath": self.points.tolist(),
                "xy": {n: self.xy[n].tolist() for n in NAMES},
                "xy_nojitter": {n: self.info["xy_nojitter"][n].tolist() for n in NAMES},
            },
        }


@dataclasses.dataclass(frozen=True)
class StereoSceneSettings:
    """The options of a simulated stereo scene (:func:`stereo_scene`,
    :func:`stereo_scene_truth`; module docstring). ``jitter_px``: across-track amplitude of the
    true models' attitude jitter (px; along track a quarter of it), ``jitter_period_lines``
    its period (image lines); ``exact_rpc``: deliver RPCs fitted to the exact jitter-free
    models instead of a perturbed copy; ``relief_m``: terrain relief (default
    :func:`default_relief_m`); ``render``: how the images are formed
    (:class:`RenderSettings`). Checked when made: a bad value raises :class:`SimulationError`
    naming the field.

    Several dates of one site: ``site_seed`` gives the scene the ground (terrain and texture)
    of the scene of that seed (same size and relief), seen by this seed's images (attitude
    wobble, vendor errors, jitter phases); ``view_angle_deg`` the pair's along-track view angle
    (``left`` ``+``, ``right`` ``-``; default 11.3: base/height 0.45); ``change`` a height change
    of the ground on this date (:class:`TerrainChange`), in the images and the truth DSM."""

    jitter_px: float = 0.0
    jitter_period_lines: float = 1000.0
    exact_rpc: bool = False
    relief_m: float | None = None
    render: RenderSettings = RenderSettings()
    site_seed: int | None = None
    view_angle_deg: float = PleiadesSettings().view_angle_deg
    change: TerrainChange | None = None

    def __post_init__(self):
        a, p = self.jitter_px, self.jitter_period_lines
        sc.require(sc.is_real(a) and math.isfinite(a) and a >= 0, "jitter_px", "be >= 0", a)
        ok = sc.is_real(p) and math.isfinite(p) and p >= 10
        sc.require(ok, "jitter_period_lines", "be >= 10", p)
        if 2 * math.pi * a / p > 0.5:
            raise SimulationError(
                f"a jitter of {a} px ({{}}) over {p} lines folds the image over itself "
                "(2 pi A / P must stay below 0.5)", "jitter_px"
            )  # fmt: skip
        r = self.relief_m
        ok = r is None or (sc.is_real(r) and math.isfinite(r) and 0 < r <= 2000)
        sc.require(ok, "relief_m", "be in (0, 2000]", r)
        sc.require(isinstance(self.exact_rpc, bool), "exact_rpc", "be True or False",
                 self.exact_rpc)  # fmt: skip
        sc.require(isinstance(self.render, RenderSettings), "render", "be a RenderSettings",
                 self.render)  # fmt: skip
        seed = self.site_seed
        ok = seed is None or (sc.is_int(seed) and seed >= 0)
        sc.require(ok, "site_seed", "be an integer >= 0 or None", seed)
        v = self.view_angle_deg
        ok = sc.is_real(v) and 1.0 <= v <= 30.0
        sc.require(ok, "view_angle_deg", "be in [1, 30] (degrees)", v)
        ok = self.change is None or isinstance(self.change, TerrainChange)
        sc.require(ok, "change", "be a TerrainChange or None", self.change)


def _check_size_seed(size, seed) -> None:
    sc.require(sc.is_int(size) and size >= 64, "size", "be an integer >= 64", size)
    sc.require(sc.is_int(seed) and seed >= 0, "seed", "be an integer >= 0", seed)


def _footprint(model, terrain: Terrain, size: int, per_side: int = 64) -> np.ndarray:
    """``(4 per_side, 3)`` lon/lat/h of the image border on the terrain (a closed ring)."""
    t = np.linspace(-0.5, size - 0.5, per_side + 1)
    up, down = t[:-1], t[::-1][:-1]
    lo, hi = np.full(per_side, -0.5), np.full(per_side, size - 0.5)
    ring = np.concatenate([np.stack(edge, -1) for edge in ((up, lo), (hi, up), (down, hi),
                                                           (lo, down))])  # fmt: skip
    g = localize_on_terrain_exact(model, terrain, ring)
    if not np.all(np.isfinite(g)):
        raise SimulationError("stereo scene: an image border does not meet the terrain")
    return g


def stereo_scene_truth(
    size: int, seed: int = 0, settings: StereoSceneSettings | None = None
) -> StereoSceneTruth:
    """The models, terrain, texture, RPCs and truth points of a ``size`` x ``size`` px scene
    (module docstring) with ``settings`` (:class:`StereoSceneSettings`), deterministic in
    ``seed``, without rendering (seconds)."""
    _check_size_seed(size, seed)
    s = StereoSceneSettings() if settings is None else settings
    jitter_px, jitter_period_lines = float(s.jitter_px), float(s.jitter_period_lines)
    exact_rpc, relief_m, render = s.exact_rpc, s.relief_m, s.render
    size, seed = int(size), int(seed)
    relief = default_relief_m(size) if relief_m is None else float(relief_m)
    params = dict(size=size, seed=seed, jitter_px=float(jitter_px),
                  jitter_period_lines=float(jitter_period_lines), exact_rpc=bool(exact_rpc),
                  relief_m=relief, site_lon_deg=SITE[0], site_lat_deg=SITE[1],
                  h_min_m=SITE[2])  # fmt: skip
    if s.site_seed is not None or s.view_angle_deg != PleiadesSettings().view_angle_deg:
        params.update(site_seed=s.site_seed, view_angle_deg=float(s.view_angle_deg))
    params.update({} if s.change is None else {"change": dataclasses.asdict(s.change)})
    rng = np.random.default_rng(seed)
    h_range = (SITE[2], SITE[2] + relief)
    h_mid = 0.5 * (h_range[0] + h_range[1])
    base = pleiades_pair(rng, size, SITE[0], SITE[1], h_mid,
                         PleiadesSettings(view_angle_deg=float(s.view_angle_deg)))  # fmt: skip
    terrain, texture = draw_ground(rng, base, size, h_range, SITE[:2])
    if s.site_seed is not None:  # the ground of the scene of site_seed, drawn as it draws it
        site_rng = np.random.default_rng(int(s.site_seed))
        site_pair = pleiades_pair(site_rng, size, SITE[0], SITE[1], h_mid)
        terrain, texture = draw_ground(site_rng, site_pair, size, h_range, SITE[:2])
    if s.change is not None:
        terrain = terrain.with_changes(s.change)
    phi = rng.uniform(0.0, 2.0 * np.pi, 2)
    phases = {n: sc.round_sig(p) for n, p in jitter_phases(base, jitter_period_lines, phi).items()}
    truth = true_models(base, float(jitter_px), float(jitter_period_lines), phases)
    lo, hi = terrain_bracket(terrain, margin_m=0.0)
    pad = 0.1 * (hi - lo) + 50.0
    vendor, rpcs, reports = vendor_rpcs(rng, base, (lo - pad, hi + pad), bool(exact_rpc))

    # truth points: a grid over the left image on the terrain, seen by the right image
    u = np.linspace(0.05, 0.95, N_POINTS_SIDE) * (size - 1)
    grid = np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)
    ground = localize_on_terrain_exact(truth["left"], terrain, grid)
    ground = sc.quantize_ground(ground[np.all(np.isfinite(ground), axis=1)])
    xy = {n: sc.quantize_image(project_true(truth[n], ground)) for n in NAMES}
    inside = np.all([(v >= 0) & (v <= size - 1) for v in xy.values()], axis=(0, 2))
    ground = ground[inside]
    xy = {n: v[inside] for n, v in xy.items()}
    xy_base = {n: sc.quantize_image(sc.project(base[n], ground)) for n in NAMES}

    def stats(res):
        return {"mean_xy": res.mean(0), "rms": float(np.sqrt(np.mean(np.sum(res**2, -1)))),
                "max": float(np.max(np.linalg.norm(res, axis=-1)))}  # fmt: skip

    rpc_vs_truth = {}
    for n in NAMES:
        at = np.asarray(rpcs[n].project(ground))
        rpc_vs_truth[n] = sc.rounded(
            {"nojitter_px": stats(at - xy_base[n]), "jittered_px": stats(at - xy[n])}, 9
        )
    middle = np.argmin(np.linalg.norm(xy_base["left"] - (size - 1) / 2.0, axis=1))
    centre = ground[middle]
    gsd_m = pixel_size_on_ground_m(base["left"], xy_base["left"][middle], float(centre[2]))
    dsm = _dsm_spec(truth, terrain, size, gsd_m)
    amplitude = np.array([1.0, JITTER_ALONG_RATIO]) * float(jitter_px)
    info = {
        "params": sc.rounded(params, 12),
        "jitter": {n: {"amplitude_px": amplitude.tolist(),
                       "period_lines": float(jitter_period_lines),
                       "phase_rad": phases[n].tolist()} for n in NAMES},
        "rpc_fit": {n: sc.rounded(reports[n].to_dict(), 9) for n in NAMES},
        "rpc_vs_truth": rpc_vs_truth,
        "gsd_m": round(gsd_m, 6),
        "base_to_height": round(base_to_height(base, centre, gsd_m), 6),
        "xy_nojitter": xy_base,
    }  # fmt: skip
    return StereoSceneTruth(base, truth, vendor, rpcs, terrain, texture, render, dsm, ground,
                            xy, info)  # fmt: skip


def _dsm_spec(truth, terrain, size, gsd_m) -> DSMSpec:
    import pyproj

    res = max(round(gsd_m * 20.0) / 20.0, 0.05)
    lon, lat = float(terrain.centre_lon_deg), float(terrain.centre_lat_deg)
    epsg = utm_epsg(utm_zone(lon, lat), north=lat >= 0)
    to_map = pyproj.Transformer.from_crs(4326, epsg, always_xy=True)
    rings = [_footprint(m, terrain, size) for m in truth.values()]
    x, y = to_map.transform(*np.concatenate(rings)[:, :2].T)
    x0, y0 = math.floor(np.min(x) / res) * res, math.ceil(np.max(y) / res) * res
    cols = int(math.ceil((np.max(x) - x0) / res))
    rows = int(math.ceil((y0 - np.min(y)) / res))
    return DSMSpec(int(epsg), float(x0), float(y0), float(res), rows, cols)


def _dsm_window(truth_scene: StereoSceneTruth, rings_cells, to_lonlat, window) -> np.ndarray:
    """Heights (float32, NaN outside both footprints) of the DSM cells of ``window``."""
    import cv2

    r0, r1, c0, c1 = window
    d = truth_scene.dsm
    xx, yy = np.meshgrid(d.x0 + d.res_m * (np.arange(c0, c1) + 0.5),
                         d.y0 - d.res_m * (np.arange(r0, r1) + 0.5))  # fmt: skip
    lon, lat = to_lonlat.transform(xx, yy)
    h = truth_scene.terrain.height_np(np.stack([np.asarray(lon), np.asarray(lat)], -1))
    mask = np.ones(h.shape, bool)
    shift = 8
    for ring in rings_cells:  # cell-index coordinates, centres at integers
        pts = np.round((ring - [c0, r0]) * (1 << shift)).astype(np.int32)
        canvas = np.zeros(h.shape, np.uint8)
        cv2.fillPoly(canvas, [pts], 1, lineType=cv2.LINE_8, shift=shift)
        mask &= canvas.astype(bool)
    return np.where(mask, h, np.nan).astype(np.float32)


def write_stereo_scene(
    scene: StereoSceneTruth,
    directory: str | os.PathLike,
    *,
    overwrite: bool = False,
    progress: bool = False,
    block_rows: int = 256,
    block_cols: int = 1024,
) -> list[pathlib.Path]:
    """Render and write ``scene`` into ``directory`` (module docstring), window by window
    (``block_rows`` x ``block_cols`` px, multiples of 256: memory is bounded by them). Refuses
    to replace an existing file unless ``overwrite`` (checked before any work); every file is
    written under a temporary name and renamed when all are complete. ``progress``: the count of
    row blocks written, with its ETA, on stderr."""
    import pyproj
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    paths = stereo_scene_files(directory)
    sc.check_writable(paths, overwrite)
    pathlib.Path(directory).mkdir(parents=True, exist_ok=True)
    size, seed = scene.size, int(scene.info["params"]["seed"])
    img_blocks = scene_windows(size, size, block_rows, block_cols)
    d = scene.dsm
    dsm_blocks = scene_windows(d.rows, d.cols, block_rows, block_cols)
    to_map = pyproj.Transformer.from_crs(4326, d.epsg, always_xy=True)
    rings = []
    for m in scene.truth.values():
        x, y = to_map.transform(*_footprint(m, scene.terrain, size)[:, :2].T)
        rings.append(np.stack([(np.asarray(x) - d.x0) / d.res_m - 0.5,
                               (d.y0 - np.asarray(y)) / d.res_m - 0.5], -1))  # fmt: skip
    to_lonlat = pyproj.Transformer.from_crs(d.epsg, 4326, always_xy=True)
    bar = Progress("stereo-scene", 2 * len(img_blocks) + len(dsm_blocks), "block",
                   enabled=progress)  # fmt: skip

    def write(dst, blocks, make, label):
        bar.note(label)
        write_blocks(dst, blocks, make, lambda: bar.update(1))

    with contextlib.ExitStack() as stack, warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        stack.callback(bar.close)
        # GDAL keeps written tiles in its block cache (by default 5 % of the RAM): a small cache
        # makes it write them out as they come, so memory does not grow with the image
        stack.enter_context(rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB))
        tmp_json = stack.enter_context(atomic_output(paths[3], overwrite))
        for i, name in enumerate(NAMES):
            tmp = stack.enter_context(
                atomic_output(paths[i], overwrite, suffix=".tmp.tif", leftovers=[".aux.xml"])
            )
            profile = image_profile(size, size, to_rasterio_rpc(scene.rpcs[name]))
            with raster_writer(tmp, profile) as dst:
                model = scene.truth[name]
                image = RenderedImage(seed, i, GAINS[name], f"{name}.tif")
                write(dst, img_blocks, lambda w, m=model, im=image: render_window(
                    m, scene.terrain, scene.texture, w, im, settings=scene.render,
                    largest_px=(block_rows, block_cols)), name)  # fmt: skip
        tmp = stack.enter_context(
            atomic_output(paths[2], overwrite, suffix=".tmp.tif", leftovers=[".aux.xml"])
        )
        transform = rasterio.Affine(d.res_m, 0.0, d.x0, 0.0, -d.res_m, d.y0)
        profile = dict(driver="GTiff", width=d.cols, height=d.rows, count=1, dtype="float32",
                       crs=f"EPSG:{d.epsg}", nodata=np.nan, tiled=True, blockxsize=256,
                       blockysize=256, compress="deflate", predictor=3,
                       transform=transform)  # fmt: skip
        with raster_writer(tmp, profile) as dst:
            write(dst, dsm_blocks, lambda w: _dsm_window(scene, rings, to_lonlat, w), "truth_dsm")
            dst.set_band_description(1, "true height above WGS84 ellipsoid (m)")
        text = json.dumps(scene.to_json(), indent=1, allow_nan=False) + "\n"
        tmp_json.write_text(text)
    return paths


def stereo_scene(
    directory: str | os.PathLike,
    size: int,
    seed: int = 0,
    settings: StereoSceneSettings | None = None,
    *,
    overwrite: bool = False,
    progress: bool = False,
) -> StereoSceneTruth:
    """Simulate a stereo scene and write it into ``directory`` (module docstring;
    :func:`stereo_scene_truth` for the scene, :func:`write_stereo_scene` for the files).
    Existing files are refused before any work unless ``overwrite``. The time taken is in
    the returned truth's ``info["seconds"]`` (``models``: the scene without its images;
    ``total``; not written)."""
    import time

    start = time.perf_counter()
    _check_size_seed(size, seed)
    sc.check_writable(stereo_scene_files(directory), overwrite)
    scene = stereo_scene_truth(size, seed, settings)
    models_s = time.perf_counter() - start
    write_stereo_scene(scene, directory, overwrite=overwrite, progress=progress)
    scene.info["seconds"] = {"models": models_s, "total": time.perf_counter() - start}
    return scene


def read_stereo_scene(directory: str | os.PathLike) -> StereoSceneTruth:
    """The :class:`StereoSceneTruth` of a folder :func:`stereo_scene` wrote: the models from
    ``truth.json``, the RPCs from the images' GeoTIFF tags."""
    from ..io import read_rpc

    d = pathlib.Path(directory)
    path = d / "truth.json"
    try:
        t = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise SimulationError(f"{path}: not JSON ({err})") from None
    if t.get("generator") != "jaxgeo.simulate.stereo_scene":
        raise SimulationError(f"{path}: not written by jaxgeo.simulate.stereo_scene")
    imgs = t["images"]
    base = {n: EphemerisModel.from_dict(imgs[n]["true_model"]) for n in NAMES}
    vendor = {n: EphemerisModel.from_dict(imgs[n]["vendor_model"]) for n in NAMES}
    params = t["params"]
    phases = {n: np.asarray(imgs[n]["jitter"]["phase_rad"]) for n in NAMES}
    truth = true_models(base, params["jitter_px"], params["jitter_period_lines"], phases)
    rpcs = {n: read_rpc(d / imgs[n]["file"]) for n in NAMES}
    pts = t["points"]
    dsm = DSMSpec(**{k: v for k, v in t["dsm"].items() if k != "file"})
    info = {
        "params": params,
        "jitter": {n: imgs[n]["jitter"] for n in NAMES},
        "rpc_fit": {n: imgs[n]["rpc_fit"] for n in NAMES},
        "rpc_vs_truth": {n: imgs[n]["rpc_vs_truth"] for n in NAMES},
        "gsd_m": t["gsd_m"],
        "base_to_height": t["base_to_height"],
        "xy_nojitter": {n: np.asarray(pts["xy_nojitter"][n]) for n in NAMES},
    }
    return StereoSceneTruth(
        base, truth, vendor, rpcs, Terrain.from_dict(t["terrain"]),
        ProceduralTexture.from_dict(t["texture"]), RenderSettings(**t["render"]), dsm,
        np.asarray(pts["lonlath"]), {n: np.asarray(pts["xy"][n]) for n in NAMES}, info,
    )  # fmt: skip
