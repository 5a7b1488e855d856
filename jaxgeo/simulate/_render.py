"""Rendered images of a simulated scene: a textured synthetic terrain seen through true models.

A :class:`GroundTexture` is an albedo raster on a local equirectangular plane (east, north metres
about the terrain's centre, as :class:`~jaxgeo.simulate._terrain.Terrain`): fields (a Voronoi
partition, each cell its own brightness and furrow pattern), a few roads, and band-limited
multi-octave noise on top, so every patch carries texture for SIFT and SGM.

:func:`render` forms an image of a sensor model by inverse mapping: each of ``supersample**2``
samples per pixel is localised on the terrain along the model's line of sight, and the texture
is sampled there (bilinear); the samples are averaged (box anti-aliasing), then a small Gaussian
point-spread function, sensor noise and quantisation follow. The line of sight of a pixel is the
line through its localisations at two heights bracketing the terrain, computed exactly by the
model on a node grid every ``node_step_px`` pixels and interpolated bilinearly between nodes
(the reprojection of rendered ground points agrees with the model to 1e-3 px, tests/simulate).
The intersection is the first one seen from the sensor: a march down the line in height steps,
then safeguarded Newton, so hidden terrain is never rendered.

Everything is deterministic in the seed.
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
from jaxtyping import Array, ArrayLike, Float

from .. import geodesy
from ..models import AbstractSensorModel
from ._scene import check_int, check_non_negative
from ._terrain import Terrain

CHUNK = 1 << 14
"""Samples per call of the jitted intersection: one compiled shape whatever the image size."""
NODE_BATCH = 1024
"""Line-of-sight nodes per call of the model's jitted localisation (one compiled shape)."""


class GroundTexture(eqx.Module):
    """Albedo ``raster[row, col]`` (0..1) on the local plane of ``terrain``'s centre: cell
    ``(row, col)`` is centred at east ``e0 + col * step_m``, north ``n0 - row * step_m``."""

    raster: Float[Array, "rows cols"]
    centre_lon_deg: Float[Array, ""]
    centre_lat_deg: Float[Array, ""]
    e0: Float[Array, ""]
    n0: Float[Array, ""]
    step_m: Float[Array, ""]

    def local(self, lonlat: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch 2"]:
        """``(lon, lat)`` deg -> local ``(east, north)`` m (the terrain's equirectangular plane)."""
        lonlat = jnp.asarray(lonlat, dtype=float)
        r = geodesy.EARTH_MEAN_RADIUS_M
        e = (
            r
            * jnp.cos(jnp.deg2rad(self.centre_lat_deg))
            * jnp.deg2rad(lonlat[..., 0] - self.centre_lon_deg)
        )
        n = r * jnp.deg2rad(lonlat[..., 1] - self.centre_lat_deg)
        return jnp.stack([e, n], axis=-1)

    def sample(self, lonlat: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        """Bilinear albedo at ``(lon, lat)`` deg (edge value outside the raster)."""
        en = self.local(lonlat)
        col = (en[..., 0] - self.e0) / self.step_m
        row = (self.n0 - en[..., 1]) / self.step_m
        rows, cols = self.raster.shape
        col = jnp.clip(col, 0.0, cols - 1.000001)
        row = jnp.clip(row, 0.0, rows - 1.000001)
        c0, r0 = jnp.floor(col).astype(int), jnp.floor(row).astype(int)
        fc, fr = col - c0, row - r0
        t = self.raster
        top = t[r0, c0] * (1 - fc) + t[r0, c0 + 1] * fc
        bottom = t[r0 + 1, c0] * (1 - fc) + t[r0 + 1, c0 + 1] * fc
        return top * (1 - fr) + bottom * fr


def ground_texture(
    rng: np.random.Generator,
    terrain: Terrain,
    extent_lonlat: ArrayLike,
    step_m: float = 1.0,
    field_size_m: float = 90.0,
    n_roads: int = 6,
    octaves_m: tuple[float, ...] = (4.0, 8.0, 16.0, 32.0, 64.0),
) -> GroundTexture:
    """A random :class:`GroundTexture` covering the lon/lat bounding box of ``extent_lonlat``
    ``(k, 2)`` (plus 50 m) at ``step_m``: fields of about ``field_size_m``, ``n_roads`` roads and
    noise octaves with the given feature sizes (m; the smallest should exceed two GSDs' worth
    of the image's sampling to stay alias-free)."""
    import cv2
    from scipy.spatial import cKDTree

    probe = GroundTexture(
        jnp.zeros((2, 2)), *(jnp.asarray(float(v)) for v in (
            terrain.centre_lon_deg, terrain.centre_lat_deg, 0.0, 0.0, step_m)),
    )  # fmt: skip
    en = np.asarray(probe.local(np.asarray(extent_lonlat, dtype=float)))
    lo, hi = en.min(0) - 50.0, en.max(0) + 50.0
    cols = int(math.ceil((hi[0] - lo[0]) / step_m)) + 1
    rows = int(math.ceil((hi[1] - lo[1]) / step_m)) + 1
    # fields: nearest of jittered seeds, on a coarse grid then upsampled (nearest)
    coarse = 2.0
    cr, cc = int(rows * step_m / coarse) + 1, int(cols * step_m / coarse) + 1
    n_seed = max(int((cr * cc * coarse**2) / field_size_m**2), 4)
    seeds = rng.uniform(0.0, 1.0, (n_seed, 2)) * [cc, cr]
    yy, xx = np.mgrid[0:cr, 0:cc]
    _, label = cKDTree(seeds).query(np.stack([xx.ravel(), yy.ravel()], -1))
    label = label.reshape(cr, cc).astype(np.int32)
    label = cv2.resize(label.astype(np.float32), (cols, rows), interpolation=cv2.INTER_NEAREST)
    label = label.astype(np.int64)
    albedo = rng.uniform(0.25, 0.75, n_seed)[label]
    # furrows: per field a direction and a period (6..16 m)
    angle = rng.uniform(0.0, np.pi, n_seed)[label]
    period = rng.uniform(6.0, 16.0, n_seed)[label]
    yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float32) * step_m
    phase = (xx * np.cos(angle) + yy * np.sin(angle)) * (2 * np.pi / period)
    albedo = albedo + 0.06 * np.sin(phase)
    albedo = cv2.GaussianBlur(albedo.astype(np.float32), (0, 0), 1.5 / step_m)
    # band-limited noise, octave by octave (white noise on a grid of the feature size, cubic)
    noise = np.zeros((rows, cols), np.float32)
    for size in octaves_m:
        n = max(int(rows * step_m / size) + 4, 4), max(int(cols * step_m / size) + 4, 4)
        grid = rng.normal(0.0, 1.0, n).astype(np.float32)
        up = cv2.resize(grid, (int(n[1] * size / step_m), int(n[0] * size / step_m)),
                        interpolation=cv2.INTER_CUBIC)  # fmt: skip
        noise += up[:rows, :cols]
    noise /= noise.std()
    albedo = albedo + 0.09 * noise
    # roads: bright anti-aliased lines 4..8 m wide
    canvas = np.zeros((rows, cols), np.float32)
    for _ in range(n_roads):
        p0 = rng.uniform(0, 1, 2) * [cols, rows]
        p1 = rng.uniform(0, 1, 2) * [cols, rows]
        width = max(int(round(rng.uniform(4.0, 8.0) / step_m)), 1)
        cv2.line(canvas, tuple(int(v) for v in p0), tuple(int(v) for v in p1), 1.0, width,
                 cv2.LINE_AA)  # fmt: skip
    albedo = albedo * (1 - canvas) + 0.85 * canvas
    raster = np.clip(albedo, 0.02, 1.0).astype(np.float32)
    return GroundTexture(
        jnp.asarray(raster), *(jnp.asarray(float(v)) for v in (
            terrain.centre_lon_deg, terrain.centre_lat_deg, lo[0], hi[1], step_m)),
    )  # fmt: skip


# --- lines of sight and their intersection with the terrain -------------------------------


@jax.jit
def _loc(model, xy, h):
    return model.localize(xy, h)


def sight_lines(
    model: AbstractSensorModel,
    xy: Float[ArrayLike, "n 2"],
    h_range_m: tuple[float, float],
    node_step_px: float = 8.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Ground points ``(n, 3)`` lon/lat/h of the lines of sight of image points ``xy`` at the
    two heights ``h_range_m``: exact on a node grid every ``node_step_px`` px over the points'
    extent, bilinear between nodes."""
    xy = np.asarray(xy, dtype=float)
    lo, hi = np.floor(xy.min(0)) - 1.0, np.ceil(xy.max(0)) + 1.0
    nx = int(math.ceil((hi[0] - lo[0]) / node_step_px)) + 1
    ny = int(math.ceil((hi[1] - lo[1]) / node_step_px)) + 1
    gx = lo[0] + node_step_px * np.arange(nx)
    gy = lo[1] + node_step_px * np.arange(ny)
    nodes = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
    u = (xy[:, 0] - lo[0]) / node_step_px
    v = (xy[:, 1] - lo[1]) / node_step_px
    j0 = np.clip(np.floor(u).astype(np.int64), 0, nx - 2)
    i0 = np.clip(np.floor(v).astype(np.int64), 0, ny - 2)
    fu, fv = (u - j0)[:, None], (v - i0)[:, None]
    out = []
    n_nodes = nodes.shape[0]
    padded = np.concatenate([nodes, np.repeat(nodes[:1], -n_nodes % NODE_BATCH, 0)])
    for h in h_range_m:
        g = np.concatenate([
            np.asarray(_loc(model, jnp.asarray(padded[s : s + NODE_BATCH]), jnp.asarray(float(h))))
            for s in range(0, padded.shape[0], NODE_BATCH)
        ])[:n_nodes]  # fmt: skip
        if not np.all(np.isfinite(g)):
            raise ValueError("render: the model does not localise every node of the image")
        g = g.reshape(ny, nx, 3)
        a = g[i0, j0] * (1 - fu) + g[i0, j0 + 1] * fu
        b = g[i0 + 1, j0] * (1 - fu) + g[i0 + 1, j0 + 1] * fu
        out.append(a * (1 - fv) + b * fv)
    return out[0], out[1]


@eqx.filter_jit
def _intersect_chunk(terrain, g_lo, g_hi, n_march, n_refine):
    """First crossing (from ``g_hi`` down) of the lines ``g_lo -> g_hi`` (lon/lat/h, linear
    in the parameter ``t``) with the terrain: ``(n, 3)`` lon/lat/h, NaN where none."""
    n = g_lo.shape[0]

    def gap(t):
        g = g_lo + t[:, None] * (g_hi - g_lo)
        return g[:, 2] - terrain.height(g[:, :2])

    def march(carry, k):
        t_up, t_dn, found = carry
        t = jnp.full(n, 1.0 - k / n_march)
        new = (~found) & (gap(t) <= 0.0)
        t_dn = jnp.where(new, t, t_dn)
        keep = found | new
        return (jnp.where(keep, t_up, t), t_dn, keep), None

    init = (jnp.ones(n), jnp.zeros(n), jnp.zeros(n, bool))
    (a, b, found), _ = jax.lax.scan(march, init, jnp.arange(1, n_march + 1))

    def refine(carry, _):  # safeguarded Newton in the bracket [b (below), a (above)]
        t, a, b = carry
        f, df = jax.jvp(gap, (t,), (jnp.ones(n),))
        a, b = jnp.where(f > 0, t, a), jnp.where(f > 0, b, t)
        step = t - f / jnp.where(df != 0, df, 1.0)
        inside = (step >= jnp.minimum(a, b)) & (step <= jnp.maximum(a, b))
        return (jnp.where(inside, step, 0.5 * (a + b)), a, b), None

    (t, _, _), _ = jax.lax.scan(refine, (0.5 * (a + b), a, b), None, length=n_refine)
    g = g_lo + t[:, None] * (g_hi - g_lo)
    ok = found & (jnp.abs(gap(t)) < 1e-4)
    return jnp.where(ok[:, None], g, jnp.nan)


def intersect_terrain(
    terrain: Terrain,
    g_lo: np.ndarray,
    g_hi: np.ndarray,
    h_range_m: tuple[float, float],
    step_m: float = 40.0,
    n_refine: int = 10,
) -> np.ndarray:
    """First intersection seen from above of the lines ``g_lo -> g_hi`` (lon/lat/h ``(n, 3)``
    at the heights ``h_range_m``, lon/lat/h linear along each: the geodetic path of a straight
    ECEF line departs from that by under a millimetre over a few hundred metres of height) with
    ``terrain``: ``(n, 3)`` lon/lat/h, NaN where none (or not converged to 0.1 mm). The march
    takes height steps of ``step_m`` (terrain features shorter than that along the ray can be
    missed), then safeguarded Newton."""
    n_march = max(int(math.ceil((h_range_m[1] - h_range_m[0]) / step_m)), 1)
    n = g_lo.shape[0]
    pad = -n % CHUNK
    lo = np.concatenate([g_lo, np.repeat(g_lo[-1:], pad, 0)])
    hi = np.concatenate([g_hi, np.repeat(g_hi[-1:], pad, 0)])
    out = [
        np.asarray(_intersect_chunk(terrain, jnp.asarray(lo[s : s + CHUNK]),
                                    jnp.asarray(hi[s : s + CHUNK]), n_march, n_refine))
        for s in range(0, n + pad, CHUNK)
    ]  # fmt: skip
    return np.concatenate(out)[:n]


def terrain_bracket(terrain: Terrain, margin_m: float = 20.0) -> tuple[float, float]:
    """Heights below and above every terrain height (m), its changes included."""
    dh = np.asarray(terrain.changes)[:, 3]
    down, up = float(np.sum(np.minimum(dh, 0.0))), float(np.sum(np.maximum(dh, 0.0)))
    return float(terrain.h_min_m) + down - margin_m, float(terrain.h_max_m) + up + margin_m


def localize_on_terrain(
    model: AbstractSensorModel, terrain: Terrain, xy: ArrayLike, node_step_px: float = 8.0
) -> np.ndarray:
    """Ground ``(n, 3)`` lon/lat/h seen at image points ``xy`` ``(n, 2)`` of ``model``: the first
    intersection of the line of sight with the terrain (NaN where none)."""
    h_range = terrain_bracket(terrain)
    g_lo, g_hi = sight_lines(model, xy, h_range, node_step_px)
    return intersect_terrain(terrain, g_lo, g_hi, h_range)


# --- images ---------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RenderSettings:
    """How an image is formed: ``supersample**2`` samples per pixel, a Gaussian PSF of
    ``psf_sigma_px``, ``value = gain * albedo + offset`` plus Gaussian noise of ``noise``
    (albedo units), quantised to ``0..levels`` (12 bits by default); line-of-sight nodes every
    ``node_step_px`` px. Checked when made (a bad value names the field)."""

    supersample: int = 2
    psf_sigma_px: float = 0.4
    noise: float = 0.004
    offset: float = 0.02
    levels: int = 4095
    node_step_px: int = 8

    def __post_init__(self):
        check_int(self, "supersample", 1)
        check_non_negative(self, "psf_sigma_px", "noise")
        check_int(self, "levels", 1)
        check_int(self, "node_step_px", 1)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


PAIR_RENDER = RenderSettings(offset=0.0, levels=1023)
"""How :func:`cartosat1_rendered` forms its images (10 bits, no offset)."""


@eqx.filter_jit
def _sample(texture, lonlat):
    return texture.sample(lonlat)


def render(
    model: AbstractSensorModel,
    terrain: Terrain,
    texture: GroundTexture,
    shape: tuple[int, int],
    rng: np.random.Generator,
    settings: RenderSettings = PAIR_RENDER,
    gain: float = 1.0,
) -> np.ndarray:
    """The image ``(rows, cols)`` of ``model`` (uint16, 0..``settings.levels``): mean albedo of
    ``supersample**2`` samples per pixel, Gaussian PSF ``psf_sigma_px``, times ``gain``, plus
    the offset and Gaussian noise (albedo units), quantised (:class:`RenderSettings`). Pixel
    ``(x, y)`` covers ``[x - 0.5, x + 0.5)``."""
    import cv2

    rows, cols = shape
    psf_sigma_px, levels = settings.psf_sigma_px, settings.levels
    s = int(settings.supersample)
    off = (np.arange(s) + 0.5) / s - 0.5
    xs = (np.arange(cols)[:, None] + off[None, :]).ravel()
    ys = (np.arange(rows)[:, None] + off[None, :]).ravel()
    xy = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    ground = localize_on_terrain(model, terrain, xy, float(settings.node_step_px))
    if not np.all(np.isfinite(ground)):
        raise ValueError("render: some pixels do not meet the terrain")
    values = np.asarray(_sample(texture, jnp.asarray(ground[:, :2])))
    img = values.reshape(rows, s, cols, s).mean(axis=(1, 3)).astype(np.float32)
    if psf_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), psf_sigma_px, borderType=cv2.BORDER_REFLECT)
    img = gain * img + settings.offset + rng.normal(0.0, settings.noise, img.shape)
    return np.clip(np.rint(img * levels), 0, levels).astype(np.uint16)


def write_image(image: np.ndarray, path: str | os.PathLike, overwrite: bool = False):
    """A single-band tiled GeoTIFF without georeferencing (the sensor model is separate)."""
    import warnings

    from rasterio.errors import NotGeoreferencedWarning

    from ..io.internal import atomic_output, raster_writer

    rows, cols = image.shape
    profile = dict(driver="GTiff", width=cols, height=rows, count=1, dtype=image.dtype.name,
                   tiled=True, blockxsize=256, blockysize=256, compress="deflate")  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with atomic_output(path, overwrite=overwrite, suffix=".tif") as tmp:
            with raster_writer(tmp, profile) as dst:
                dst.write(image, 1)
    return path


@dataclasses.dataclass(frozen=True)
class RenderedPair:
    """A simulated stereo scene (:class:`~jaxgeo.simulate._cartosat1.StereoScene`) with its
    rendered images (``names`` -> uint16 arrays), the ground texture and the GSD (m, the
    geometric mean of the reference image's pixel footprint at its centre)."""

    scene: object
    images: dict
    texture: GroundTexture
    gsd_m: float

    def save_images(self, directory: str | os.PathLike, overwrite: bool = False) -> dict:
        """Write ``<name>.tif`` per image; returns name -> path."""
        d = pathlib.Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        return {n: write_image(im, d / f"{n}.tif", overwrite) for n, im in self.images.items()}


def gsd(model: AbstractSensorModel, xy: ArrayLike, h: float) -> float:
    """Geometric mean of the ground distances (m) between a pixel and its right and lower
    neighbours at height ``h``."""
    xy = np.asarray(xy, dtype=float)
    pts = np.asarray(model.localize(np.stack([xy, xy + [1, 0], xy + [0, 1]]), h))
    e = np.asarray(geodesy.geodetic_to_ecef(pts))
    return float(math.sqrt(np.linalg.norm(e[1] - e[0]) * np.linalg.norm(e[2] - e[0])))


def cartosat1_rendered(
    seed: int = 0,
    size: int = 800,
    h_range_m: tuple[float, float] = (200.0, 500.0),
    terrain_wavelengths_m: tuple[float, float] = (500.0, 5000.0),
    supersample: int = 2,
    **scene_options,
) -> RenderedPair:
    """A Cartosat-1 fore/aft pair (:func:`~jaxgeo.simulate.cartosat1_stereo`, Cartosat-1 optics
    and orbit, ``size`` x ``size`` pixels, 36 points on a grid) rendered from a textured terrain
    through the true models (``scene_options``: more fields of
    :class:`~jaxgeo.simulate.Cartosat1Settings`). Fore and aft differ by sensor noise and a 3 %
    gain."""
    from ._cartosat1 import Cartosat1Settings, cartosat1_stereo

    options = dict(site="hobart", n_points=36, layout="grid", centre_columns=True)
    options |= scene_options
    settings = Cartosat1Settings(
        n_rows=size, n_cols=size, h_range_m=h_range_m,
        terrain_wavelengths_m=terrain_wavelengths_m, **options,
    )  # fmt: skip
    scene = cartosat1_stereo(seed, settings)
    rng = np.random.default_rng([seed, 1])
    corners = np.array([[0, 0], [size - 1, 0], [0, size - 1], [size - 1, size - 1]], float)
    h_mid = 0.5 * (h_range_m[0] + h_range_m[1])
    extent = np.concatenate(
        [np.asarray(m.localize(corners, h))[:, :2] for m in scene.truth.values()
         for h in h_range_m]
    )  # fmt: skip
    texture = ground_texture(rng, scene.terrain, extent)
    images = {
        name: render(
            scene.truth[name],
            scene.terrain,
            texture,
            (size, size),
            rng,
            dataclasses.replace(PAIR_RENDER, supersample=supersample),
            gain=(1.0, 0.97)[i],
        )  # fmt: skip
        for i, name in enumerate(scene.names)
    }
    centre = np.array([(size - 1) / 2.0] * 2)
    return RenderedPair(scene, images, texture, gsd(scene.truth[scene.names[0]], centre, h_mid))
