"""A semi-global matcher in JAX: census cost, aggregation over 8 (or 4) paths, sub-pixel
winner-take-all, uniqueness and left-right checks -- the same program on a CPU, GPU or TPU.

Disparity convention (shareloc/CARS, as :mod:`._dense`): left epipolar pixel ``(x, y)`` matches
right ``(x + d, y)``.

The stages, all integer until the sub-pixel step (costs are counts of differing census bits):

- **Census** of a ``CENSUS_ROWS x CENSUS_COLS`` (7 x 7) window: one bit per neighbour brighter
  than the centre (by more than ``CENSUS_TOLERANCE`` grey levels: a uniform patch's noise sets
  no bit), 48 bits in a ``uint64``. Why census: it is invariant to the gain and offset
  between two dates or sensors (the uint8 stretches of the two images differ), and it is the
  cost of the GPU matchers that are fast (libSGM, Hirschmueller's own implementations).
- **Cost volume** ``C[y, x, k] = popcount(census_l[y, x] ^ census_r[y, x + d_k])`` in uint8,
  ``H x W x D``; a match outside the right image costs all 48 bits (its disparity loses).
- **Aggregation** (Hirschmueller 2008) along each path ``r``:
  ``L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d+-1) + P1, min_k L_r(p-r, k) + P2)
  - min_k L_r(p-r, k)``, in uint16 (``L_r <= C_max + P2``: a sum over 8 paths fits). ``P2``
  falls with the intensity step along the path, ``P2 / (1 + |dI| / P2_GREY)`` (never below
  ``P1 + 1``): disparity jumps are cheaper at image edges, where surfaces end. Each path is a
  ``jax.lax.scan`` over rows (vertical and diagonal paths; a diagonal shifts the carried row
  by one column per step) or over columns (horizontal paths), vectorised across the other axis
  and the disparities.
- **Winner-take-all** on the summed costs; the **equiangular** sub-pixel fit (Shimizu &
  Okutomi: the better model for census's L1-like costs than a parabola) to the raw costs
  summed over ``SUBPIXEL_WINDOW`` squares around the winner (the aggregated costs lock to whole
  pixels: on a band-limited shift of 0.4 px, median errors 0.23 px against 0.03 px); the
  **uniqueness**
  test (the best cost ``(100 + uniqueness) / 100`` times below every cost off its +-1
  neighbours, as OpenCV's) and the **left-right** check: the right image's winners from the
  same summed volume (OpenCV's way), a left disparity kept when the right pixel it lands on
  chooses it back within ``disp12_max_diff`` px.

One program is compiled per (rows, columns, disparities) bucket (:func:`bucket`): bands and
tiles of nearby sizes share it, padded with edge pixels, their padding cut off afterwards.
OpenCV's speckle filter (connected components, host-side) is applied to the result by the
caller (:func:`~jaxgeo.stereo._dense.sgm_disparity`).

**Memory.** The cost volume and the path sums grow as rows x columns x disparities
(:func:`band_bytes`, 20 bytes a voxel; measured on the CPU, the peak resident set of a
512 x 1024 px band: 479 MB at 64 disparities, 931 MB at 128, ~14.5 bytes a voxel). Before
anything runs, :func:`census_sgm` takes the largest chunk of rows whose program fits a budget
(:func:`memory_budget`: a share of the device's free memory, or the caller's
``memory_bytes``), and matches the image chunk by chunk, each with ``CHUNK_OVERLAP_ROWS`` of
context above and below (the vertical paths' reach), all chunks of one shape (one program);
when even ``MIN_CHUNK_ROWS`` rows cannot fit it refuses (:class:`SGMMemoryError`) before any
work, instead of dying in the middle of a scene.
"""

from __future__ import annotations

import functools
import os

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import JaxgeoError

CENSUS_ROWS, CENSUS_COLS = 7, 7
"""Census window (px): 48 bits, one ``uint64`` per pixel."""
CENSUS_BITS = CENSUS_ROWS * CENSUS_COLS - 1
CENSUS_TOLERANCE = 4
"""Grey levels (of the uint8 images) by which a neighbour must be brighter than the centre to
set its census bit. Without it a uniform patch (a road, a roof) gets bits drawn by its noise,
its costs are noise at every disparity, and the paths carry wrong disparities from its edges
into it; with it a uniform patch's census is all zeros, it costs the same at every disparity,
and the smoothness term decides. Measured on simulated 300 px scenes (seeds 23, 5, 41), DSM
cells > 1 m off truth: 1.43, 1.23, 0.61 % without, 0.11, 0.10, 0.03 % with (OpenCV's SGBM
0.11, 0.04, 0.00 %), in lines along the scenes' roads; RMS 0.255, 0.218, 0.158 m -> 0.160,
0.132, 0.095 m (OpenCV 0.167, 0.140, 0.092). Not tuned: 3 and 8 give the same (seed 23: 0.12,
0.09 %); the real s2p Pleiades pair: fill 0.988 -> 0.990 (OpenCV 0.991), within 1 px of
OpenCV 98.2 -> 98.3 %."""
P2_GREY = 48.0
"""Intensity step (grey levels of the uint8 images) that halves ``P2`` along a path."""
SUBPIXEL_WINDOW = 5
"""Window (px) of the raw costs summed for the sub-pixel fit."""
UNUSED_COST = 255
"""Cost of a padded disparity (beyond the range asked): never a winner."""
ROW_BUCKET, COL_BUCKET, DISPARITY_BUCKET = 64, 64, 16
"""Shapes are rounded up to these multiples before compiling (:func:`bucket`)."""


BYTES_PER_VOXEL = 20
"""Memory (bytes) of a program per voxel of its bucketed cost volume (pixel x disparity): XLA's
own memory analysis (arguments + outputs + temporaries, CPU, jax 0.10.2) of the aggregation's
program, the larger of the two, is 14.4-18.6 bytes a voxel over 128-576 rows, 256-1088 columns,
64-128 disparities (the census program 1.1-1.3); 20 keeps a margin for the runtime."""
BYTES_PER_PIXEL = 64
"""Memory (bytes) per pixel of the bucket outside the volume: the census (2 x 8), images,
winners, disparities."""
CHUNK_OVERLAP_ROWS = 32
"""Rows of context above and below a chunk (dropped after matching): the reach of the vertical
and diagonal paths that matters (as the band overlap of :class:`~._dense.BandMatcher`)."""
MIN_CHUNK_ROWS = 64
"""The fewest rows a chunk keeps (below that, the overlap costs more than the rows kept)."""
DEVICE_SHARE = 0.8
"""Share of an accelerator's free memory a band may use (XLA's allocator holds the rest)."""
HOST_SHARE = 0.25
"""Share of the host's available memory a band may use on the CPU (the tile workers of one
machine, each with its images and DSM tile, share the rest)."""


class SGMMemoryError(JaxgeoError, MemoryError):
    """The dense matcher cannot match even :data:`MIN_CHUNK_ROWS` rows within its memory budget;
    the message says what is needed, what is allowed and which setting raises it."""


def band_bytes(rows: int, cols: int, n_disp: int) -> int:
    """Memory (bytes) of matching ``rows x cols`` pixels over ``n_disp`` disparities in one
    program (their :func:`bucket`; :data:`BYTES_PER_VOXEL`)."""
    rows_b, cols_b, n_b = bucket(rows, cols, n_disp)
    return BYTES_PER_VOXEL * rows_b * cols_b * n_b + BYTES_PER_PIXEL * rows_b * cols_b


def _host_available_bytes() -> int:
    """The host's available memory (``MemAvailable`` of /proc/meminfo; else free pages)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def memory_available(device=None) -> tuple[int, str, float]:
    """Bytes ``device`` (default: JAX's default device) has free, what they are, and the share
    of them a band may use: an accelerator's free memory (its ``bytes_limit`` less
    ``bytes_in_use``, :data:`DEVICE_SHARE`), else the host's available memory (a CPU, whose
    device reports no limit; :data:`HOST_SHARE`). Read at each call."""
    device = jax.devices()[0] if device is None else device
    try:
        stats = device.memory_stats() or {}
    except Exception:  # a backend without memory statistics
        stats = {}
    if stats.get("bytes_limit"):
        free = int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
        return free, f"{device.platform}'s free memory", DEVICE_SHARE
    return _host_available_bytes(), "the host's available memory", HOST_SHARE


def memory_budget(device=None) -> tuple[int, str]:
    """Bytes a band may use on ``device`` and where that comes from: its share of
    :func:`memory_available` (it follows what else holds memory)."""
    free, what, share = memory_available(device)
    return int(share * free), f"{share:.0%} of {what}"


def chunk_rows(rows: int, cols: int, n_disp: int, budget_bytes: int, source: str = "") -> int:
    """Rows kept per chunk so that a chunk (with :data:`CHUNK_OVERLAP_ROWS` above and below)
    fits ``budget_bytes`` (:func:`band_bytes`): ``rows`` when the whole image fits, else a
    multiple of the row bucket less the overlaps. Raises :class:`SGMMemoryError` (naming
    ``source``, the budget's origin) when not even :data:`MIN_CHUNK_ROWS` rows fit."""
    if band_bytes(rows, cols, n_disp) <= budget_bytes:
        return int(rows)
    step, over = ROW_BUCKET, 2 * CHUNK_OVERLAP_ROWS
    least = -(-(MIN_CHUNK_ROWS + over) // step) * step  # the bucket of the smallest chunk
    if band_bytes(least, cols, n_disp) > budget_bytes:
        need = band_bytes(least, cols, n_disp)
        raise SGMMemoryError(
            f"the JAX dense matcher needs {need / 2**20:.0f} MB for {MIN_CHUNK_ROWS} rows (and "
            f"{over} rows of context) of {cols} px over {n_disp} disparities, more than its "
            f"budget of {budget_bytes / 2**20:.0f} MB ({source or 'as given'}): raise it with "
            "SGMSettings(memory_mb=...) (CLI --matcher-memory MB), make the tiles narrower "
            "(--tile) or use --matcher opencv"
        )  # fmt: skip
    fit = least
    while fit + step <= rows + over and band_bytes(fit + step, cols, n_disp) <= budget_bytes:
        fit += step
    return int(min(fit - over, rows))


def bucket(rows: int, cols: int, n_disp: int) -> tuple[int, int, int]:
    """The compiled shape that serves ``rows x cols`` images and ``n_disp`` disparities."""

    def up(n, m):
        return -(-int(n) // m) * m

    return up(rows, ROW_BUCKET), up(cols, COL_BUCKET), up(n_disp, DISPARITY_BUCKET)


def census(image: jax.Array) -> jax.Array:
    """Census bit-strings (``uint64``, ``CENSUS_BITS`` bits) of a ``(H, W)`` uint8 image: bit set
    where the neighbour is brighter than the centre by more than :data:`CENSUS_TOLERANCE`
    grey levels; edge pixels replicated outside."""
    hr, hc = CENSUS_ROWS // 2, CENSUS_COLS // 2
    rows, cols = image.shape
    img = image.astype(jnp.int16)
    pad = jnp.pad(img, ((hr, hr), (hc, hc)), mode="edge")
    bits = jnp.zeros((rows, cols), jnp.uint64)
    for i in range(CENSUS_ROWS):
        for j in range(CENSUS_COLS):
            if (i, j) == (hr, hc):
                continue
            brighter = pad[i : i + rows, j : j + cols] > img + CENSUS_TOLERANCE
            bits = (bits << jnp.uint64(1)) | brighter.astype(jnp.uint64)
    return bits


def cost_volume(census_l, census_r, disp_min, n_used, n_disp: int, cols=None) -> jax.Array:
    """``C[y, x, k]`` (uint8): differing census bits of left ``(x, y)`` and right
    ``(x + disp_min + k, y)``; ``CENSUS_BITS`` where that pixel is outside the right image's
    first ``cols`` columns (default: all), ``UNUSED_COST`` for ``k >= n_used`` (padding of the
    disparity bucket)."""
    width = census_l.shape[1]
    cols = width if cols is None else cols
    x = jnp.arange(width)
    # the census once, not fused into (recomputed for) every disparity
    census_l, census_r = jax.lax.optimization_barrier((census_l, census_r))
    # the right image's columns x + disp_min + k as slices of it padded by a full width
    padded = jnp.pad(census_r, ((0, 0), (width, width)))
    start = jnp.clip(width + disp_min, 0, 2 * width)

    def one(k):
        inside = (x + disp_min + k >= 0) & (x + disp_min + k < cols)
        right = jax.lax.dynamic_slice_in_dim(padded, start + k, width, axis=1)
        c = jax.lax.population_count(census_l ^ right).astype(jnp.uint8)
        c = jnp.where(inside[None, :], c, jnp.uint8(CENSUS_BITS))
        return jnp.where(k < n_used, c, jnp.uint8(UNUSED_COST))

    return jnp.moveaxis(jax.vmap(one)(jnp.arange(n_disp)), 0, -1)


def _path_step(prev, cost, grey_step, p1, p2):
    """One step of the recurrence for a row of pixels: ``prev`` ``(..., n, D)`` the previous
    pixels' ``L_r`` (zeros where a path starts), ``cost`` ``(n, D)``, ``grey_step`` ``(..., n)``
    the intensity step along the path."""
    low = jnp.min(prev, axis=-1, keepdims=True)
    up = jnp.concatenate([prev[..., :1], prev[..., :-1]], axis=-1)
    down = jnp.concatenate([prev[..., 1:], prev[..., -1:]], axis=-1)
    p2_eff = p2 / (1.0 + grey_step / P2_GREY)
    p2_eff = jnp.maximum(p2_eff, p1 + 1).astype(jnp.uint16)[..., None]
    best = jnp.minimum(jnp.minimum(prev, jnp.minimum(up, down) + p1), low + p2_eff)
    return cost + best - low


def _shift(a, shift, axis=0):
    """``a`` moved by ``shift`` (-1, 0, 1) along ``axis`` (``out[i] = a[i - shift]``), zeros
    entering."""
    if shift == 0:
        return a
    a = jnp.moveaxis(a, axis, 0)
    zero = jnp.zeros_like(a[:1])
    out = jnp.concatenate([zero, a[:-1]]) if shift > 0 else jnp.concatenate([a[1:], zero])
    return jnp.moveaxis(out, 0, axis)


def _aggregate_rows(cost, image, shifts, p1, p2):
    """The summed ``L_r`` (uint16 ``(H, W, D)``) of the paths along the rows, down and up in
    one scan (half the sequential steps), each moving ``shifts[i]`` columns per row (0:
    vertical; +-1: diagonal)."""
    img = image.astype(jnp.float32)
    # the intensity one step back along each path, per row: (H, n_paths, W), down and up
    prev_img = jnp.stack([_shift(img, s, axis=1) for s in shifts], axis=1)
    back_down = jnp.concatenate([prev_img[:1], prev_img[:-1]])
    back_up = jnp.concatenate([prev_img[1:], prev_img[-1:]])
    steps = jnp.stack([jnp.abs(img[:, None, :] - back_down),
                       jnp.abs(img[:, None, :] - back_up)[::-1]], axis=1)  # fmt: skip
    n = len(shifts)

    def step(carry, row):
        c, g = row  # (2, W, D) uint8: this row going down and its mirror going up
        prev = jnp.stack([_shift(carry[:, i], s, axis=1) for i, s in enumerate(shifts)], 1)
        new = _path_step(prev, c[:, None].astype(jnp.uint16), g, p1, p2)
        return new, jnp.sum(new, axis=1, dtype=jnp.uint16)

    rows, cols, n_disp = cost.shape
    init = jnp.zeros((2, n, cols, n_disp), jnp.uint16)
    _, total = jax.lax.scan(step, init, (jnp.stack([cost, cost[::-1]], axis=1), steps))
    return total[:, 0] + total[::-1, 1]


def aggregate(cost, image, p1, p2, n_paths: int = 8) -> jax.Array:
    """Sum over ``n_paths`` (8: the 4 axes and 4 diagonals; 4: the axes) of the path costs
    ``L_r`` (uint16 ``(H, W, D)``) of cost volume ``cost`` of uint8 ``image`` (the left)."""
    total = _aggregate_rows(cost, image, (-1, 0, 1) if n_paths == 8 else (0,), p1, p2)
    # horizontal paths: the same scans over the transposed volume
    across = _aggregate_rows(jnp.swapaxes(cost, 0, 1), image.T, (0,), p1, p2)
    return total + jnp.swapaxes(across, 0, 1)


def _window_costs(cost, k, size):
    """``(H, W, 3)``: the raw costs at disparities ``k - 1, k, k + 1`` of each pixel (``k``
    ``(H, W)``) summed over the ``size x size`` square around it (zeros outside; the 3 x size**2
    gathers, not a box over every disparity)."""
    half = size // 2
    rows, cols, n_disp = cost.shape
    padded = jnp.pad(cost, ((half, half), (half, half), (0, 0)))
    ks = jnp.clip(k[..., None] + jnp.arange(-1, 2), 0, n_disp - 1)  # (H, W, 3)
    total = jnp.zeros((rows, cols, 3), jnp.uint16)
    for dy in range(size):
        for dx in range(size):
            part = jax.lax.slice(padded, (dy, dx, 0), (dy + rows, dx + cols, n_disp))
            total = total + jnp.take_along_axis(part, ks, axis=-1).astype(jnp.uint16)
    return total


def _equiangular(total, k, n_disp):
    """Sub-pixel offset (-0.5..0.5) of the minimum at ``k`` of ``total`` ``(..., D)``: two lines
    of opposite slopes through the three costs around it (0 at the range's ends)."""
    km, kp = jnp.clip(k - 1, 0, n_disp - 1), jnp.clip(k + 1, 0, n_disp - 1)
    at = functools.partial(jnp.take_along_axis, total.astype(jnp.float32), axis=-1)
    cm, c0, cp = (at(i[..., None])[..., 0] for i in (km, k, kp))
    slope = jnp.maximum(cm - c0, cp - c0)
    inner = (k > 0) & (k < n_disp - 1) & (slope > 0)
    off = jnp.where(inner, (cm - cp) / (2.0 * jnp.where(slope > 0, slope, 1.0)), 0.0)
    return jnp.clip(off, -0.5, 0.5)


@functools.partial(jax.jit, static_argnames=("n_disp",))
def _costs(left8, right8, disp_min, n_used, n_disp):
    """The cost volume of a bucketed pair (:func:`cost_volume`; ``n_used``: the disparities and
    columns not padding). A program of its own: made in the program that aggregates it, XLA
    (CPU, jax 0.10) gives the volume a layout that makes the path scans ~6x slower (measured
    on 512 x 1024 px, 64 disparities, with or without an optimisation barrier)."""
    n_used, cols = n_used
    return cost_volume(census(left8), census(right8), disp_min, n_used, n_disp, cols)


@functools.partial(jax.jit, static_argnames=("n_paths",))
def _match(cost, left8, disp_min, n_used, p1, p2, checks, n_paths):
    """Disparities (float32 ``(H, W)``, NaN = none) of a bucketed pair from its cost volume;
    ``n_used``: the disparities and columns not padding; ``checks``: ``(uniqueness_ratio,
    disp12_max_diff)``."""
    uniqueness, lr_tol = checks
    n_used, cols = n_used
    width, n_disp = left8.shape[1], cost.shape[-1]
    # materialised once, not fused into (recomputed by) each of its readers
    total = jax.lax.optimization_barrier(aggregate(cost, left8, p1, p2, n_paths))
    k = jnp.argmin(total, axis=-1)
    best = jnp.min(total, axis=-1).astype(jnp.int32)
    # uniqueness: every cost off the winner's +-1 higher by the ratio
    ks = jnp.arange(n_disp)
    near = jnp.abs(ks - k[..., None]) <= 1
    others = jnp.min(jnp.where(near, jnp.iinfo(jnp.uint16).max, total), axis=-1)
    unique = others.astype(jnp.int32) * 100 > best * (100 + uniqueness)
    # the right image's winners from the same volume: right pixel xr takes the k minimising
    # total[y, xr - d_k, k] (a full winner-take-all; OpenCV's keeps, per right pixel, the
    # winner of the cheapest left pixel landing on it, which on simulated pairs removes almost
    # nothing: an occlusion's pixels land on pixels that other left pixels win)
    x = jnp.arange(width)
    xl = x[:, None] - (disp_min + ks)[None, :]  # (W, D)
    inside = (xl >= 0) & (xl < cols) & (ks < n_used)[None, :]
    gathered = jnp.take_along_axis(total, jnp.clip(xl, 0, width - 1)[None], axis=1)
    big = jnp.iinfo(jnp.uint16).max
    right_k = jnp.argmin(jnp.where(inside[None], gathered, big), axis=-1)
    # sub-pixel: the aggregated costs lock to whole pixels (their smoothness terms flatten the
    # minimum: a 0.4 px shift reads ~0.2 px); the window sums of the raw costs do not
    local = _window_costs(cost, k, SUBPIXEL_WINDOW)
    disp = (disp_min + k).astype(jnp.float32) + _equiangular(local, jnp.ones_like(k), 3)
    disp = jnp.where((k > 0) & (k < n_disp - 1), disp, (disp_min + k).astype(jnp.float32))
    # as OpenCV's: consistent when the right pixel below or above x + d chooses d back
    consistent = jnp.zeros_like(unique)
    for xr_f in (jnp.floor(x[None, :] + disp), jnp.ceil(x[None, :] + disp)):
        xr = xr_f.astype(jnp.int32)
        lands = (xr >= 0) & (xr < cols)
        back = jnp.take_along_axis(right_k, jnp.clip(xr, 0, width - 1), axis=1)
        d_back = (xr - x[None, :] - disp_min).astype(jnp.int32)  # its k
        consistent |= lands & (jnp.abs(back - d_back) <= lr_tol)
    ok = unique & consistent & (k < n_used)
    return jnp.where(ok, disp, jnp.nan)


def census_sgm(left8, right8, disp_min, disp_max, penalties, checks=(10, 1), n_paths=8,
               memory_bytes=None):  # fmt: skip
    """Disparity ``d`` (float64 ``(H, W)``, NaN = no match) of two uint8 epipolar images of one
    shape, searched over the whole pixels of ``[disp_min, disp_max]`` (shareloc convention):
    census cost, ``n_paths`` (8 or 4) semi-global paths with ``penalties`` ``(p1, p2)`` (census
    bits; ``p2`` adaptive to the intensity step), equiangular sub-pixel fit, ``checks`` =
    ``(uniqueness_ratio %, disp12_max_diff px)`` as OpenCV's. Runs on JAX's default device; one
    program per :func:`bucket`; in chunks of rows that fit ``memory_bytes`` (``None``:
    :func:`memory_budget`), refused before any work when none fits (:class:`SGMMemoryError`)."""
    if np.shape(left8) != np.shape(right8) or np.ndim(left8) != 2:
        raise ValueError(f"census_sgm: images of shapes {left8.shape} and {right8.shape}; "
                         "expected two 2-D images of one shape")  # fmt: skip
    if n_paths not in (4, 8):
        raise ValueError(f"census_sgm: n_paths {n_paths}: expected 4 or 8")
    lo, hi = int(np.floor(disp_min)), int(np.ceil(disp_max))
    if hi < lo:
        raise ValueError(f"census_sgm: empty disparity range [{disp_min:g}, {disp_max:g}]")
    rows, cols = np.shape(left8)
    if memory_bytes is None:
        budget, source = memory_budget()
    else:  # never past what the device has: such a band would be killed mid-run
        free, what, _ = memory_available()
        budget = min(int(memory_bytes), free)
        source = "as set" if budget == int(memory_bytes) else f"as set, capped at {what}"
    keep = chunk_rows(rows, cols, hi - lo + 1, budget, source)
    if keep >= rows:
        return _one_chunk(left8, right8, lo, hi, penalties, checks, n_paths)
    # chunks of one shape (one program): each window CHUNK_OVERLAP_ROWS wider on both sides
    # where the image goes on, moved inside it at the ends
    window = min(rows, keep + 2 * CHUNK_OVERLAP_ROWS)
    out = np.empty((rows, cols), np.float64)
    for r0 in range(0, rows, keep):
        r1 = min(r0 + keep, rows)
        ra = int(np.clip(r0 - CHUNK_OVERLAP_ROWS, 0, rows - window))
        disp = _one_chunk(left8[ra : ra + window], right8[ra : ra + window], lo, hi,
                          penalties, checks, n_paths)  # fmt: skip
        out[r0:r1] = disp[r0 - ra : r1 - ra]
    return out


def _one_chunk(left8, right8, lo, hi, penalties, checks, n_paths):
    """:func:`census_sgm` of whole-pixel range ``[lo, hi]`` in one program."""
    rows, cols = np.shape(left8)
    rows_b, cols_b, n_b = bucket(rows, cols, hi - lo + 1)
    pad = ((0, rows_b - rows), (0, cols_b - cols))
    # on the device (where the images are already, or the default one)
    left_b, right_b = (jnp.pad(jnp.asarray(a, jnp.uint8), pad, mode="edge")
                       for a in (left8, right8))  # fmt: skip
    used = (jnp.int32(hi - lo + 1), jnp.int32(cols))
    cost = _costs(left_b, right_b, jnp.int32(lo), used, n_b)
    p1, p2 = penalties
    disp = _match(
        cost, left_b, jnp.int32(lo), used,
        jnp.uint16(p1), jnp.float32(p2), tuple(jnp.int32(c) for c in checks), n_paths,
    )  # fmt: skip
    return np.asarray(disp, np.float64)[:rows, :cols]
