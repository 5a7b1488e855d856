"""Streaming rendering of a simulated scene: windows of rows x columns, each a pure function of
the model, the terrain, the texture and the seed, written into the GeoTIFF as they come.

A window is rendered by inverse mapping (as :func:`jaxgeo.simulate._render.render`, reorganised
for speed and bounded memory):

1. nodes every ``node_step_px`` px (a grid anchored at the image origin): the model localises
   each at two heights bracketing the terrain, and the first intersection of that line with the
   terrain is found by a march and safeguarded Newton (:func:`~._render.intersect_terrain`);
2. pixel centres: the line of sight and the intersection interpolated bilinearly from the nodes
   (the lines to ~1e-3 px, the intersection to a few cm), then one Newton step on the exact
   intersection of that line with the terrain (quadratic convergence: ~1e-7 m from a few cm;
   a pixel whose start is over :data:`NEWTON_START_M` away gets the full search instead);
3. ``supersample**2`` samples per pixel: ground positions interpolated linearly between the
   neighbouring pixel centres' intersections (a quarter pixel away: ~1e-4 px), the texture
   sampled there and averaged (box anti-aliasing);
4. a Gaussian point-spread function, gain and offset, sensor noise, quantisation.

The PSF needs a halo of pixels around the window: they are rendered too (the model extends
beyond the image), so a pixel's value does not depend on the window it was rendered in. The
noise comes from one generator per 256 x 256 tile of the image (seeded by the seed, the image
and the tile). So the output is the same for any window size that is a multiple of the tile size.

Memory is bounded by the window size (rows x columns x samples), independent of the image size;
every jitted call has one fixed shape (nodes of the largest window, chunks of pixels or samples);
the GeoTIFFs are tiled (256 x 256) and each tile is written once, complete.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..models import AbstractSensorModel, localize_points
from ._render import RenderSettings, terrain_bracket
from ._stereo_scene_models import JitteredModel, intersect_lines, smooth_part
from ._terrain import Terrain

TILE = 256
"""GeoTIFF tile size (px) and noise tile; window sizes are multiples of it."""
SAMPLE_CHUNK = 1 << 16
"""Pixels or samples per call of a jitted stage (one compiled shape)."""
NEWTON_START_M = 0.5
"""A pixel's single Newton step is trusted when its interpolated start is this close (height
gap, m) to the terrain: the error after the step is about ``tan(view)^2 |H''| e^2 / 2`` for a
start ``e`` away and terrain curvature ``|H''|`` (< 1e-2 /m here), below 1e-4 m; the starts are
within a few cm (nodes every 8 px on smooth terrain). Other pixels get the full search."""


@dataclasses.dataclass(frozen=True)
class RenderedImage:
    """The image of a scene a window belongs to: ``seed`` (the scene's) and ``index`` (of the
    image in the scene) seed its noise, ``gain`` scales its albedo, ``name`` names it in
    errors."""

    seed: int
    index: int
    gain: float = 1.0
    name: str = "image"


def scene_windows(
    rows: int, cols: int, block_rows: int = TILE, block_cols: int = 4 * TILE
) -> list[list[tuple[int, int, int, int]]]:
    """Row blocks of windows ``(r0, r1, c0, c1)`` covering a ``rows`` x ``cols`` image;
    ``block_rows`` and ``block_cols`` must be multiples of :data:`TILE`."""
    if block_rows % TILE or block_cols % TILE or block_rows <= 0 or block_cols <= 0:
        raise ValueError(
            f"block sizes must be positive multiples of {TILE}, got {block_rows} x {block_cols}"
        )
    return [
        [(r0, min(r0 + block_rows, rows), c0, min(c0 + block_cols, cols))
         for c0 in range(0, cols, block_cols)]
        for r0 in range(0, rows, block_rows)
    ]  # fmt: skip


def _psf_radius(sigma: float) -> int:
    return int(math.ceil(3.0 * sigma)) if sigma > 0 else 0


def _grid_shape(sample_rows: int, sample_cols: int, step: int) -> tuple[int, int]:
    """Node-grid shape that covers any window of up to ``sample_rows`` x ``sample_cols`` px."""
    return sample_rows // step + 3, sample_cols // step + 3


def _node_grid(model, terrain, i0, j0, shape, step, h_range):
    """``shape + (5,)``: at the nodes ``(step * (j0 + b), step * (i0 + a))`` the lon, lat of the
    line of sight at ``h_range[0]`` and at ``h_range[1]``, and the line parameter ``t`` of its
    first terrain intersection (NaN where none)."""
    gy = step * np.arange(i0, i0 + shape[0], dtype=float)
    gx = step * np.arange(j0, j0 + shape[1], dtype=float)
    nodes = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
    g = [localize_points(model, nodes, h) for h in h_range]
    ground = intersect_lines(terrain, g[0], g[1], h_range)
    t = (ground[:, 2] - h_range[0]) / (h_range[1] - h_range[0])
    return np.concatenate([g[0][:, :2], g[1][:, :2], t[:, None]], -1).reshape(*shape, 5)


def _lines(grid, uv, xp):
    """Bilinear interpolation of the node ``grid`` at node coordinates ``uv`` ``(n, 2)``:
    ``(lo, hi, t)`` lon/lat at the two heights and the intersection parameter."""
    ny, nx = grid.shape[0], grid.shape[1]
    j = xp.clip(xp.floor(uv[:, 0]), 0, nx - 2).astype(xp.int32)
    i = xp.clip(xp.floor(uv[:, 1]), 0, ny - 2).astype(xp.int32)
    fu, fv = (uv[:, 0] - j)[:, None], (uv[:, 1] - i)[:, None]
    q = (grid[i, j] * (1 - fu) + grid[i, j + 1] * fu) * (1 - fv) + (
        grid[i + 1, j] * (1 - fu) + grid[i + 1, j + 1] * fu
    ) * fv
    return q[:, 0:2], q[:, 2:4], q[:, 4]


@eqx.filter_jit
def _intersect_pixels(terrain, grid, h_range, uv):
    """lon/lat ``(n, 2)`` where the lines of sight at node coordinates ``uv`` meet the terrain,
    and whether each is trusted: one Newton step from the interpolated intersection, trusted
    when that start was within :data:`NEWTON_START_M` of the surface (module docstring)."""
    lo, hi, t = _lines(grid, uv, jnp)
    h0, h1 = h_range[0], h_range[1]

    def gap(t):
        return h0 + t * (h1 - h0) - terrain.height(lo + t[:, None] * (hi - lo))

    f, df = jax.jvp(gap, (t,), (jnp.ones_like(t),))
    t = t - f / df
    ok = jnp.isfinite(t) & (jnp.abs(f) < NEWTON_START_M)
    return lo + t[:, None] * (hi - lo), ok


def _full_search(terrain, grid, uv, h_range) -> np.ndarray:
    """lon/lat ``(n, 2)`` of the first terrain intersection of the interpolated lines of sight
    at ``uv`` by the full search (march then Newton); NaN where a line misses the terrain."""
    lo, hi, _ = _lines(grid, uv, np)
    n = len(uv)
    g_lo = np.concatenate([lo, np.full((n, 1), h_range[0])], -1)
    g_hi = np.concatenate([hi, np.full((n, 1), h_range[1])], -1)
    return intersect_lines(terrain, g_lo, g_hi, h_range)[:, :2]


def _chunked(fn, arrays: np.ndarray, *args):
    """``fn(*args, chunk)`` over fixed-size chunks of ``arrays`` (edge-padded), concatenated."""
    n = len(arrays)
    padded = np.concatenate([arrays, np.repeat(arrays[:1], -n % SAMPLE_CHUNK, 0)])
    outs = [fn(*args, jnp.asarray(padded[k : k + SAMPLE_CHUNK]))
            for k in range(0, len(padded), SAMPLE_CHUNK)]  # fmt: skip
    if isinstance(outs[0], tuple):
        return tuple(np.concatenate([np.asarray(o[i]) for o in outs])[:n]
                     for i in range(len(outs[0])))  # fmt: skip
    return np.concatenate([np.asarray(o) for o in outs])[:n]


@eqx.filter_jit
def _sample(texture, lonlat):
    return texture.sample(lonlat)


def _noise(seed: int, image_index: int, r0, r1, c0, c1, sigma: float) -> np.ndarray:
    """Gaussian noise of the window from one generator per :data:`TILE` tile of the image."""
    out = np.empty((r1 - r0, c1 - c0))
    for tr in range(r0 // TILE, (r1 - 1) // TILE + 1):
        for tc in range(c0 // TILE, (c1 - 1) // TILE + 1):
            tile = np.random.default_rng([seed, 7, image_index, tr, tc]).normal(
                0.0, sigma, (TILE, TILE)
            )
            ra, rb = max(r0, tr * TILE), min(r1, (tr + 1) * TILE)
            ca, cb = max(c0, tc * TILE), min(c1, (tc + 1) * TILE)
            out[ra - r0 : rb - r0, ca - c0 : cb - c0] = tile[
                ra - tr * TILE : rb - tr * TILE, ca - tc * TILE : cb - tc * TILE
            ]
    return out


def _subsamples(centres: np.ndarray, s: int) -> np.ndarray:
    """``(R - 2, s, C - 2, s, 2)`` sample positions of the inner pixels of the pixel-centre
    grid ``centres`` ``(R, C, 2)``: linear between neighbouring centres at the offsets
    ``(k + 0.5) / s - 0.5`` px."""
    offsets = (np.arange(s) + 0.5) / s - 0.5

    def along(a, axis):  # (..., n, ...) -> (..., n - 2, s, ...) on ``axis``
        n = a.shape[axis]
        mid = np.take(a, np.arange(1, n - 1), axis=axis)
        out = []
        for o in offsets:
            nb = np.take(a, np.arange(1, n - 1) + (1 if o > 0 else -1), axis=axis)
            out.append(mid * (1 - abs(o)) + nb * abs(o))
        return np.stack(out, axis=axis + 1)

    return along(along(centres, 0), 2)


def window_ground(
    model: AbstractSensorModel,
    terrain: Terrain,
    window: tuple[int, int, int, int],
    step: int = 8,
    largest: tuple[int, int] = (0, 0),
    name: str = "image",
) -> np.ndarray:
    """``(rows, cols, 2)`` lon/lat where the lines of sight of the pixel centres of ``window``
    ``(r0, r1, c0, c1)`` first meet the terrain (steps 1-2 of the module docstring; the jitter
    of a :class:`JitteredModel` applied exactly per pixel). ``largest``: the largest window of
    the run (one node-grid shape for all)."""
    ra, rb, ca, cb = (int(v) for v in window)
    h_range = terrain_bracket(terrain)
    yy, xx = np.mgrid[ra:rb, ca:cb]
    xy = np.stack([xx.ravel(), yy.ravel()], -1).astype(float)
    # the jitter is applied exactly per pixel, the smooth model interpolated between nodes
    smooth, xy = smooth_part(model, xy)
    margin = 0
    if isinstance(model, JitteredModel):
        margin = int(math.ceil(float(np.max(np.abs(np.asarray(model.amplitude_px)))))) + 1
    shape = _grid_shape(max(rb - ra, largest[0]) + 2 * margin,
                        max(cb - ca, largest[1]) + 2 * margin, step)  # fmt: skip
    i0, j0 = math.floor((ra - margin) / step), math.floor((ca - margin) / step)
    grid = _node_grid(smooth, terrain, i0, j0, shape, step, h_range)
    uv = np.stack([xy[:, 0] / step - j0, xy[:, 1] / step - i0], -1)
    centres, ok = _chunked(_intersect_pixels, uv, terrain, jnp.asarray(grid),
                           jnp.asarray(h_range, dtype=float))  # fmt: skip
    if not ok.all():  # not converged from the interpolated start: the full search there
        centres[~ok] = _full_search(terrain, grid, uv[~ok], h_range)
    if not np.all(np.isfinite(centres)):
        raise ValueError(
            f"{name}: some lines of sight in rows {ra}..{rb - 1}, columns {ca}..{cb - 1} do "
            "not meet the terrain"
        )
    return centres.reshape(rb - ra, cb - ca, 2)


def render_window(
    model: AbstractSensorModel,
    terrain: Terrain,
    texture,
    window: tuple[int, int, int, int],
    image: RenderedImage,
    *,
    settings: RenderSettings | None = None,
    largest_px: tuple[int, int] = (TILE, 4 * TILE),
) -> np.ndarray:
    """Pixels ``[r0, r1) x [c0, c1)`` of the image of ``model`` (uint16 ``(r1 - r0, c1 - c0)``;
    module docstring). ``texture`` has ``sample(lonlat)``; the noise is seeded by ``image``'s
    seed and index (tiles of :data:`TILE`), which also gives the gain and the name in errors;
    ``largest_px``: rows x columns of the largest window of the run (sets the one compiled
    shape of the node grid); ``settings``: how the image is formed (default
    :class:`RenderSettings`)."""
    import cv2

    settings = RenderSettings() if settings is None else settings
    block_rows, block_cols = (int(v) for v in largest_px)
    r0, r1, c0, c1 = (int(v) for v in window)
    s = int(settings.supersample)
    step = int(settings.node_step_px)
    halo = _psf_radius(settings.psf_sigma_px) + 1  # + 1: the neighbours of the sub-samples
    ra, rb, ca, cb = r0 - halo, r1 + halo, c0 - halo, c1 + halo
    centres = window_ground(model, terrain, (ra, rb, ca, cb), step,
                            (block_rows + 2 * halo, block_cols + 2 * halo),
                            image.name)  # fmt: skip
    samples = _subsamples(centres, s)
    values = _chunked(_sample, samples.reshape(-1, 2), texture)
    img = values.reshape(rb - ra - 2, s, cb - ca - 2, s).mean(axis=(1, 3)).astype(np.float32)
    inner = halo - 1
    if inner:
        k = 2 * inner + 1
        img = cv2.GaussianBlur(img, (k, k), settings.psf_sigma_px, borderType=cv2.BORDER_REFLECT)
        img = img[inner:-inner, inner:-inner]
    img = image.gain * img.astype(float) + settings.offset
    img = img + _noise(image.seed, image.index, r0, r1, c0, c1, settings.noise)
    return np.clip(np.rint(img * settings.levels), 0, settings.levels).astype(np.uint16)


def write_blocks(
    dst,
    blocks: list[list[tuple[int, int, int, int]]],
    make: Callable[[tuple[int, int, int, int]], np.ndarray],
    advance: Callable[[], None] | None = None,
) -> None:
    """Write ``make(window)`` into band 1 of the open rasterio dataset ``dst`` for every window
    of ``blocks``, calling ``advance()`` after each row block."""
    from rasterio.windows import Window

    for row in blocks:
        for r0, r1, c0, c1 in row:
            dst.write(make((r0, r1, c0, c1)), 1, window=Window(c0, r0, c1 - c0, r1 - r0))
        if advance is not None:
            advance()


def image_profile(rows: int, cols: int, rpcs) -> dict:
    """rasterio profile of a rendered image: uint16, tiled, DEFLATE with a horizontal
    predictor, the RPC in the GeoTIFF RPC tag, no georeferencing."""
    return dict(
        driver="GTiff", width=cols, height=rows, count=1, dtype="uint16", tiled=True,
        blockxsize=TILE, blockysize=TILE, compress="deflate", predictor=2, rpcs=rpcs,
    )  # fmt: skip
