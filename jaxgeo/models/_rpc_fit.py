"""Terrain-independent RPC fitting to any sensor model (how vendors make their RPCs).

The model's validity cube is sampled by a 3D grid: an ``nx x ny`` grid of image points covering
the whole image, each localised at ``nh`` height layers spanning ``h_range``. Offsets and scales
come from the grid (centre and half range of lon, lat, height, column and row). The 39 unknowns
of each image coordinate (20 numerator + 19 denominator coefficients, the constant denominator
term fixed to 1) are found by linearised least squares ``Num - v (Den - 1) = v`` with Tikhonov
(ridge) regularisation, then refined by reweighting every equation with ``1 / Den`` of the
previous solution, which turns it into the least-squares solution of the true rational residual
(Tao & Hu 2001, "A comprehensive study of the rational function model for photogrammetric
processing", PE&RS 67(12): the iterative least-squares method with regularisation).

Accuracy is reported on the fit grid and on an independent check grid placed at the cell
midpoints (half a cell away in column, row and height).

The localisation, the fit and the check projections run as kept programs
(:mod:`jaxgeo._runtime.kept`): a second run of ``jaxgeo adjust`` or ``jaxgeo strip``
traces none of them (a 10 000-tie ``jaxgeo adjust``, paired: 0.5 s less warm, ~1 s less cold).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._runtime.kept import kept, kept_points
from ._base import AbstractSensorModel
from ._rpc import B_TO_A, RPC, TermOrder, monomials

DEFAULT_GRID = (21, 21, 7)
DEFAULT_REGULARIZATION = 1e-11
DEFAULT_ITERATIONS = 3


@dataclasses.dataclass(frozen=True)
class RPCFitReport:
    """Residuals ``RPC(ground) - model image`` in pixels on the fit and check grids.

    ``*_rms_px`` / ``*_max_px`` are the RMS and maximum of the residual vector length;
    ``*_rms_xy_px`` the per-axis RMS ``(x, y)``.
    """

    fit_rms_px: float
    fit_max_px: float
    fit_rms_xy_px: tuple[float, float]
    check_rms_px: float
    check_max_px: float
    check_rms_xy_px: tuple[float, float]
    n_fit: int
    n_check: int
    grid: tuple[int, int, int]
    h_range_m: tuple[float, float]

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _grid(n_cols, n_rows, h_range, grid, check: bool):
    nx, ny, nh = grid
    xs = np.linspace(0.0, n_cols - 1.0, nx)
    ys = np.linspace(0.0, n_rows - 1.0, ny)
    hs = np.linspace(h_range[0], h_range[1], nh)
    if check:  # cell midpoints: never a fit point, inside the fitted cube
        xs, ys, hs = (0.5 * (v[1:] + v[:-1]) for v in (xs, ys, hs))
    hh, yy, xx = np.meshgrid(hs, ys, xs, indexing="ij")
    return np.stack([xx.ravel(), yy.ravel()], -1), hh.ravel()


CHUNKS = (512, 8192)
"""Points per compiled call (:func:`jaxgeo._runtime.kept.kept_points`): the small size below
``CHUNKS[1]`` points (a refit grid, GCPs), compiled quickly; the large one from there on,
compiled for speed (a call's own cost, ~0.3 ms, spread over 16x the points). At most two
programs per model type whatever the number of points."""


@kept_points(CHUNKS)
def _localize_chunk(model, image, h):
    return model.localize(image, h)


def localize_points(model: AbstractSensorModel, image, h) -> np.ndarray:
    """``model.localize`` of ``(n, 2)`` image points at heights ``h`` (broadcast), compiled over
    fixed-size chunks (:data:`CHUNKS`): at most two programs per model type, any number of
    points."""
    image = np.asarray(image, dtype=float).reshape(-1, 2)
    h = np.broadcast_to(np.asarray(h, dtype=float), image.shape[:1])
    return _localize_chunk(model, image, h)


@kept_points(CHUNKS)
def _project_chunk(model, ground):
    return model.project(ground)


def project_points(model: AbstractSensorModel, ground) -> np.ndarray:
    """``model.project`` of ``(..., 3)`` points, compiled over fixed-size chunks (as
    :func:`localize_points`)."""
    ground = np.asarray(ground, dtype=float)
    out = _project_chunk(model, ground.reshape(-1, 3))
    return out.reshape(*ground.shape[:-1], 2)


@kept
def _project_rpc(rpc, ground):
    return rpc.project(ground)


def _solve(design, target, mask, reg, iterations):
    """Rational fit of one coordinate: ``target ~ design @ a / (design @ [1, b])``.

    Normal equations of the weighted linear system, equilibrated by their diagonal, with the
    ridge ``reg`` added to the unit diagonal, solved by Cholesky (39 x 39, cheap).
    """
    n = design.shape[-1]
    cols = jnp.concatenate([design, -target[:, None] * design[:, 1:]], axis=1)

    def step(_, coef):
        w = mask / (design @ jnp.concatenate([jnp.ones(1), coef[n:]]))
        wc = w[:, None] * cols
        normal = wc.T @ wc
        s = 1.0 / jnp.sqrt(jnp.diag(normal))
        # ridge on the equilibrated unknowns: ``reg`` is relative to the unit diagonal
        normal = s[:, None] * normal * s[None, :] + reg * jnp.eye(2 * n - 1)
        chol = jax.scipy.linalg.cho_factor(normal)
        return s * jax.scipy.linalg.cho_solve(chol, s * (wc.T @ (w * target)))

    return jax.lax.fori_loop(0, iterations, step, jnp.zeros(2 * n - 1))


@kept
def _fit_normalized(ground_n, image_n, mask, reg, perm, iterations):
    design = monomials(ground_n)[:, perm]
    coef = jax.vmap(lambda v: _solve(design, v, mask, reg, iterations))(image_n.T)
    return coef[:, :20], jnp.concatenate([jnp.ones((2, 1)), coef[:, 20:]], axis=1)


def _stats(res: np.ndarray) -> tuple[float, float, tuple[float, float]]:
    res = res[np.all(np.isfinite(res), axis=-1)]
    length = np.hypot(res[:, 0], res[:, 1])
    rms_xy = np.sqrt(np.mean(res**2, axis=0))
    return (
        float(np.sqrt(np.mean(length**2))),
        float(length.max()),
        (float(rms_xy[0]), float(rms_xy[1])),
    )


def _finite_mask(ground: np.ndarray, what: str) -> np.ndarray:
    ok = np.all(np.isfinite(ground), axis=-1)
    bad = int(np.sum(~ok))
    if bad > 0.1 * len(ok):
        raise ValueError(
            f"fit_rpc: the model could not localise {bad} of {len(ok)} {what} "
            "grid points (is the image size or the height range wrong?)"
        )
    return ok


def fit_rpcs(
    models: Sequence[AbstractSensorModel],
    n_cols: int | None = None,
    n_rows: int | None = None,
    h_range: Sequence[float] = (0.0, 1000.0),
    *,
    order: TermOrder = "RPC00B",
    grid: tuple[int, int, int] = DEFAULT_GRID,
    regularization: float = DEFAULT_REGULARIZATION,
    iterations: int = DEFAULT_ITERATIONS,
) -> list[tuple[RPC, RPCFitReport]]:
    """:func:`fit_rpc` for several models (e.g. the sub-scenes of a strip) with one grid:
    the localisation and solve compile once and serve every model."""
    models = list(models)
    if not models:
        return []
    first = models[0]
    n_cols = int(n_cols if n_cols is not None else first.n_cols)
    n_rows = int(n_rows if n_rows is not None else first.n_rows)
    h0, h1 = (float(v) for v in h_range)
    nx, ny, nh = (int(v) for v in grid)
    if not h1 > h0:
        raise ValueError(f"fit_rpc: h_range must be increasing, got {tuple(h_range)}")
    if min(nx, ny, nh) < 4:
        raise ValueError(
            f"fit_rpc: grid needs at least 4 points per axis for cubic terms, got {grid}"
        )
    if order not in ("RPC00B", "RPC00A"):
        raise ValueError(f"unknown RPC term order {order!r}; expected 'RPC00A' or 'RPC00B'")
    image, h = _grid(n_cols, n_rows, (h0, h1), (nx, ny, nh), check=False)
    c_image, c_h = _grid(n_cols, n_rows, (h0, h1), (nx, ny, nh), check=True)
    i_off = np.array([0.5 * (n_cols - 1), 0.5 * (n_rows - 1)])
    i_scale = np.maximum(i_off, 0.5)
    image_n = jnp.asarray((image - i_off) / i_scale)
    perm = jnp.asarray(np.arange(20) if order == "RPC00B" else B_TO_A)
    out = []
    for model in models:
        both = localize_points(model, np.concatenate([image, c_image]), np.concatenate([h, c_h]))
        ground, c_ground = both[: len(h)], both[len(h) :]
        mask, c_mask = _finite_mask(ground, "fit"), _finite_mask(c_ground, "check")
        lo, hi = np.nanmin(ground, axis=0), np.nanmax(ground, axis=0)
        g_off, g_scale = 0.5 * (lo + hi), 0.5 * (hi - lo)
        g_off[2], g_scale[2] = 0.5 * (h0 + h1), 0.5 * (h1 - h0)
        ground_n = np.where(mask[:, None], (ground - g_off) / g_scale, 0.0)
        num, den = _fit_normalized(
            ground_n, image_n, mask.astype(float), np.asarray(float(regularization)), perm,
            int(iterations),
        )  # fmt: skip
        rpc = RPC(num, den, g_off, g_scale, i_off, i_scale, order=order)
        fit_res = np.asarray(_project_rpc(rpc, np.nan_to_num(ground))) - image
        chk_res = np.asarray(_project_rpc(rpc, np.nan_to_num(c_ground))) - c_image
        f = _stats(np.where(mask[:, None], fit_res, np.nan))
        c = _stats(np.where(c_mask[:, None], chk_res, np.nan))
        report = RPCFitReport(*f, *c, int(mask.sum()), int(c_mask.sum()), (nx, ny, nh), (h0, h1))
        out.append((rpc, report))
    return out


def fit_rpc(
    model: AbstractSensorModel,
    n_cols: int | None = None,
    n_rows: int | None = None,
    h_range: Sequence[float] = (0.0, 1000.0),
    *,
    order: TermOrder = "RPC00B",
    grid: tuple[int, int, int] = DEFAULT_GRID,
    regularization: float = DEFAULT_REGULARIZATION,
    iterations: int = DEFAULT_ITERATIONS,
) -> tuple[RPC, RPCFitReport]:
    """Fit an RPC to ``model`` over its image (``n_cols x n_rows`` px) and ``h_range`` (m).

    Args:
        model: any sensor model with ``localize`` (and ``project``).
        n_cols, n_rows: image size; default ``model.n_cols`` / ``model.n_rows``.
        h_range: ``(h_min, h_max)`` ellipsoidal heights (m) of the validity cube.
        order: term order in which the coefficients are solved for (RPC00B or RPC00A); the
            returned :class:`RPC` writes either.
        grid: ``(nx, ny, nh)`` image columns, rows and height layers of the fit grid; the check
            grid has ``(nx - 1, ny - 1, nh - 1)`` points at the cell midpoints.
        regularization: ridge weight on the coefficients of the normalised problem.
        iterations: linearised solves (the first unweighted, then reweighted by ``1 / Den``).

    Returns ``(rpc, report)`` (:class:`RPCFitReport`).
    """
    return fit_rpcs(
        [model],
        n_cols,
        n_rows,
        h_range,
        order=order,
        grid=grid,
        regularization=regularization,
        iterations=iterations,
    )[0]
