"""Triangulation of matches and disparity maps through the sensor models.

Two estimators:

- ``"intersect"`` (default): :func:`jaxgeo.intersect.intersect`, the image-space least-squares
  intersection of jaxgeo (vmapped Gauss-Newton, point covariance, reprojection residuals).
- ``"los_midpoint"``: the estimator of CNES shareloc/CARS, for comparison with their point
  clouds: each line of sight is the straight ECEF chord between the model's localisations at two
  heights, the point is the least-squares midpoint of the lines. When the models carry a
  relative bias the rays miss each other and the two estimators differ (4.5 cm in height on the
  Ventoux pair, whose rays miss by ~1.1 m).

A disparity ``d`` at left epipolar pixel ``(xe, ye)`` matches right epipolar ``(xe + d, ye)``;
both go through the rectification grids to sensor coordinates.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import JaxgeoError
from ..geodesy import ecef_to_geodetic, geodetic_to_ecef
from ..intersect import IntersectResult, intersect
from ..models import AbstractSensorModel
from ._rectification import EpipolarGrids
from ._uncertainty import intersection_jacobian

VALIDITY_MARGIN = 0.1
"""How far past its RPC's validity cube a 3D point still counts as inside, in cube half-widths
(most points outside: the model does not fit the images)."""
BLUNDER_MARGIN = 0.5
"""How far past the validity cube a single 3D point is dropped as a blunder (half-widths)."""


EXCESS_BLOCK = 16384
"""Points per block of :func:`_validity_excess` (a DSM tile checks a million points per model)."""


class StereoError(JaxgeoError, ValueError):
    """A stereo pair jaxgeo refuses: the message names the images and what does not fit (an ROI
    the other image does not see, tie points or 3D points outside the models' validity, an
    offset across the epipolar lines larger than any relative bias)."""


def outside_validity(
    points: np.ndarray, model: AbstractSensorModel, margin: float = VALIDITY_MARGIN
) -> np.ndarray:
    """``(n,)`` True where a finite lon/lat/h point lies outside ``model``'s RPC validity cube
    widened by ``margin`` half-widths (never for a model without an RPC)."""
    with np.errstate(invalid="ignore"):
        return _validity_excess(points, model) > 1.0 + margin


def _validity_excess(points: np.ndarray, model: AbstractSensorModel) -> np.ndarray:
    """``(n,)`` the largest of a lon/lat/h point's offsets from ``model``'s RPC validity cube's
    centre in half-widths (0 for a model without an RPC, NaN for a point that is not finite)."""
    points = np.asarray(points, dtype=float)
    rpc = model.base_rpc()
    if rpc is None:
        return np.where(np.all(np.isfinite(points), axis=-1), 0.0, np.nan)
    offset = np.asarray(rpc.ground_offset, dtype=float)
    scale = np.abs(np.asarray(rpc.ground_scale, dtype=float))
    flat = points.reshape(-1, 3)
    out = np.empty(flat.shape[0])
    for s in range(0, flat.shape[0], EXCESS_BLOCK):  # temporaries in cache, not 1e6 x 3
        block, most = flat[s : s + EXCESS_BLOCK], out[s : s + EXCESS_BLOCK]
        np.abs(block[:, 0] - offset[0], out=most)
        most /= scale[0]
        for k in (1, 2):  # NaN propagates through np.maximum
            np.maximum(most, np.abs(block[:, k] - offset[k]) / scale[k], out=most)
    return out.reshape(points.shape[:-1])


def describe_validity(model: AbstractSensorModel) -> str:
    """The RPC validity cube of ``model`` in words (lon, lat, h ranges)."""
    rpc = model.base_rpc()
    if rpc is None:
        return "no RPC validity cube"
    lo, hi = np.asarray(rpc.validity_cube(), dtype=float)
    return (
        f"lon {lo[0]:.4f}..{hi[0]:.4f} deg, lat {lo[1]:.4f}..{hi[1]:.4f} deg, "
        f"h {lo[2]:.0f}..{hi[2]:.0f} m"
    )


def _refuse_outside(points, models, paths, what, excess=None):
    """:class:`StereoError` when most of the finite ``points`` lie outside the validity cube of
    one or both models (named with their images; ``excess``: their :func:`_validity_excess`
    per model, when known)."""
    finite = np.all(np.isfinite(points), axis=1)
    n = int(finite.sum())
    if excess is None:
        excess = [_validity_excess(points, m) for m in models]
    with np.errstate(invalid="ignore"):
        counts = [int((e > 1.0 + VALIDITY_MARGIN).sum()) for e in excess]
    bad = [i for i, c in enumerate(counts) if n and c > 0.5 * n]
    if bad:
        h = points[finite, 2]
        whose = " and ".join(f"of {paths[i]} ({describe_validity(models[i])})" for i in bad)
        raise StereoError(
            f"stereo: {max(counts[i] for i in bad)} of the {n} {what} of {paths[0]} and "
            f"{paths[1]} lie outside the validity of the model{'s' * (len(bad) > 1)} {whose}, "
            f"at heights {np.percentile(h, 5):.0f}..{np.percentile(h, 95):.0f} m: the models "
            "do not fit the images (a model of another image or scene?)"
        )


def check_ties(
    ground: np.ndarray,
    models: Sequence[AbstractSensorModel],
    paths: Sequence,
    min_ties: int = 10,
) -> None:
    """:class:`StereoError` naming the images when fewer than ``min_ties`` of the tie points
    ``ground`` ``(n, 3)`` triangulate, or most of them lie outside a model's validity cube: the
    models do not fit the images (``paths``: the images of ``models``)."""
    finite = np.all(np.isfinite(ground), axis=1)
    if finite.sum() < min_ties:
        raise StereoError(
            f"stereo: only {finite.sum()} of the {len(ground)} tie points between {paths[0]} "
            f"and {paths[1]} triangulate: the models do not fit the images"
        )
    _refuse_outside(ground, models, paths, "tie points")


def drop_outside_validity(
    points: np.ndarray, models: Sequence[AbstractSensorModel], paths: Sequence
) -> dict:
    """Most of the 3D points ``(n, 3)`` outside a model's validity cube: :class:`StereoError`
    naming the images whose models they leave. Otherwise the points farther than
    ``BLUNDER_MARGIN`` outside a cube are set to NaN (in place: gross mismatches); returns
    ``n_points`` (kept) and ``n_points_outside_validity`` (dropped)."""
    n = int(np.all(np.isfinite(points), axis=1).sum())
    excess = [_validity_excess(points, m) for m in models]
    _refuse_outside(points, models, paths, "3D points", excess)
    with np.errstate(invalid="ignore"):
        outside = np.logical_or.reduce([e > 1.0 + BLUNDER_MARGIN for e in excess])
    points[outside] = np.nan
    return dict(n_points=n - int(outside.sum()), n_points_outside_validity=int(outside.sum()))


def disparity_to_matches(
    grids: EpipolarGrids,
    disparity: np.ndarray,
    row_off: int = 0,
    col_off: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Left and right sensor ``(x, y)`` ``(rows, cols, 2)`` of a disparity map whose pixel
    ``(0, 0)`` is epipolar pixel ``(col_off, row_off)``; NaN disparities give NaN."""
    disparity = np.asarray(disparity, dtype=float)
    rows = row_off + np.arange(disparity.shape[0])
    cols = col_off + np.arange(disparity.shape[1])
    xe, ye = np.meshgrid(cols.astype(float), rows.astype(float))
    left = grids.to_sensor("left", np.stack([xe, ye], axis=-1))
    right = grids.to_sensor("right", np.stack([xe + disparity, ye], axis=-1))
    return left, right


def los_heights(model: AbstractSensorModel) -> tuple[float, float]:
    """Two heights spanning the model's validity: an RPC's ``h_off -/+ h_scale / 2`` (as shareloc
    and CARS), otherwise the reference height -/+ 500 m."""
    rpc = model.base_rpc()  # a wrapped model (e.g. RPC + bias): its RPC's validity range
    if rpc is not None:
        h0, hs = float(rpc.ground_offset[2]), float(rpc.ground_scale[2])
        return h0 - hs / 2, h0 + hs / 2
    h0 = float(model.reference_ground()[2])
    return h0 - 500.0, h0 + 500.0


@jax.jit
def _chords(model, xy, h_low, h_high):
    a = geodetic_to_ecef(model.localize(xy, h_low))
    b = geodetic_to_ecef(model.localize(xy, h_high))
    return a, b


def _midpoint(starts, ends):
    """Least-squares point closest to the lines ``starts -> ends`` ``(n_views, n, 3)``; the
    solve is done about the mean start (ECEF is ~6e6 m)."""
    origin = starts.mean(axis=0)
    u = ends - starts
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    proj = np.eye(3) - u[..., :, None] * u[..., None, :]  # (v, n, 3, 3)
    a = proj.sum(axis=0)
    b = np.einsum("vnij,vnj->ni", proj, starts - origin).reshape(-1, 3)
    ok = np.all(np.isfinite(b), axis=-1)
    sol = np.full_like(b, np.nan)
    sol[ok] = np.linalg.solve(a[ok], b[ok][..., None])[..., 0]
    return origin + sol


def triangulate_los_midpoint(
    models: Sequence[AbstractSensorModel], image_points: np.ndarray, chunk: int = 65536
) -> np.ndarray:
    """shareloc/CARS triangulation: ``image_points`` ``(n, n_views, 2)`` -> ``(n, 3)`` lon/lat/h."""
    image_points = np.asarray(image_points, dtype=float)
    out = np.full((image_points.shape[0], 3), np.nan)
    for s in range(0, image_points.shape[0], chunk):
        xy = image_points[s : s + chunk]
        starts, ends = [], []
        for v, m in enumerate(models):
            h0, h1 = los_heights(m)
            a, b = _chords(m, jnp.asarray(xy[:, v]), h0, h1)
            starts.append(np.asarray(a))
            ends.append(np.asarray(b))
        ecef = _midpoint(np.stack(starts), np.stack(ends))
        out[s : s + chunk] = np.asarray(ecef_to_geodetic(jnp.asarray(ecef)))
    return out


def triangulate(
    models: Sequence[AbstractSensorModel],
    image_points: np.ndarray,
    method: str = "intersect",
    sigma_px: float = 0.5,
    chunk: int = 65536,
) -> tuple[np.ndarray, IntersectResult | None]:
    """Triangulate ``image_points`` ``(n, n_views, 2)`` (NaN rows give NaN).

    Returns ``(ground (n, 3), result)``: ``result`` is the :class:`IntersectResult` (covariance,
    residuals, s0) for ``method="intersect"`` (concatenated over chunks, host arrays), ``None``
    for ``"los_midpoint"``.
    """
    if method == "los_midpoint":
        return triangulate_los_midpoint(models, image_points, chunk), None
    if method != "intersect":
        raise ValueError(f"triangulate: unknown method {method!r} (intersect, los_midpoint)")
    image_points = np.asarray(image_points, dtype=float)
    parts = []
    n = image_points.shape[0]
    for s in range(0, n, chunk):
        xy = image_points[s : s + chunk]
        pad = chunk - xy.shape[0] if n > chunk else 0  # one compiled shape for every chunk
        if pad:
            xy = np.concatenate([xy, np.full((pad, *xy.shape[1:]), np.nan)])
        res = intersect(models, xy, sigma_px=sigma_px)
        res = jax.tree.map(lambda a, k=xy.shape[0] - pad: np.asarray(a)[:k], res)
        parts.append(res)
    result = jax.tree.map(lambda *a: np.concatenate(a), *parts)
    return np.asarray(result.ground), result


MIN_LATTICE_POINTS = 50_000
"""Fewer dense matches than this are triangulated one by one (the lattice's nodes would cost as
much)."""
LATTICE_CHUNK = 16384
"""Nodes per triangulation call of :func:`disparity_lattice` (NaN-padded: one compiled shape)."""
LATTICE_TOL_M = 1e-3
"""Largest error (m, any coordinate) of the lattice's interpolation at its check points (the
centres of its cells, where a trilinear interpolation errs most) for it to be used; beyond it
every point is triangulated on its own."""
LATTICE_CHECKS = 2048
"""Cell centres whose exact triangulation checks the lattice (at most; spread over its cells)."""
JACOBIAN_TOL = 1e-3
"""Largest relative error (of the vector's norm) of the lattice's interpolated ``d up / d xy``
(:func:`~jaxgeo.stereo._uncertainty.intersection_jacobian`) at its check points for it to be
used by the height sigmas (0.1 %: the sigmas to well under 1 %); beyond it the sigmas take the
Jacobian point by point."""
LATTICE_BLOCK = 4096
"""Points per block of :meth:`DisparityLattice.interpolate` (its temporaries stay in cache)."""


@dataclass(frozen=True)
class DisparityLattice:
    """Triangulated points of a rectified pair on a lattice of epipolar nodes ``(xe, ye, d)``
    (left epipolar pixel and disparity), interpolated trilinearly in between
    (:func:`disparity_lattice`).

    Why: a 1 Mpx tile has a million matches, and a million Gauss-Newton intersections cost
    seconds (the tile's largest stage), while the point is a smooth function of ``(xe, ye, d)``:
    the grids are bilinear between their nodes (the lattice's ``xe``, ``ye`` nodes are theirs)
    and the models smooth over a node step. So is the intersection's sensitivity to the image
    coordinates, which the height sigma needs per point (a ``jacfwd`` per point cost as much as
    the intersections). ``values`` ``(nd, ny, nx, 4 + 2 N)``: lon, lat, h minus those of
    ``centre`` (deg, deg, m: small numbers, interpolated in float64 to 1e-12), the
    intersection's height sigma (m; NaN for ``los_midpoint``) and ``d up / d (x, y)`` of each of
    the ``N`` images (m/px, image-major) at the nodes ``origin + index * step`` (``(xe, ye, d)``
    px); ``check_error_m``: the largest difference (m) between the interpolation and the exact
    triangulation at the check points; ``jacobian_check_error``: the largest relative error of
    the interpolated ``d up / d xy`` there."""

    origin: tuple[float, float, float]
    step: tuple[float, float, float]
    centre: np.ndarray
    values: np.ndarray
    check_error_m: float
    jacobian_check_error: float = float("inf")

    @property
    def usable(self) -> bool:
        return bool(self.check_error_m <= LATTICE_TOL_M)

    @property
    def jacobian_usable(self) -> bool:
        return bool(self.usable and self.jacobian_check_error <= JACOBIAN_TOL)

    def interpolate(self, xe, ye, d) -> np.ndarray:
        """``(n, 4 + 2 N)`` lon, lat, h minus ``centre``'s, the height sigma and ``d up / d xy``
        at ``(n,)`` epipolar points; NaN outside the lattice or next to a node without a point
        (:meth:`blocks`)."""
        xe = np.asarray(xe, dtype=float).reshape(-1)
        out = np.full((len(xe), self.values.shape[-1]), np.nan)
        for rows, value in self.blocks(xe, ye, d):
            out[rows] = value
        return out

    def blocks(self, xe, ye, d):
        """The trilinear interpolation of :meth:`interpolate` block by block: yields ``(rows,
        values)``, the indices of a block's points inside the lattice and their ``(m, 4 + 2
        N)`` values, so that a caller writes each channel where it belongs (a 1 Mpx tile's
        ``(n, 8)`` float64 array and its copies cost page faults).

        One pass for every channel, in blocks of :data:`LATTICE_BLOCK` points: the eight corner
        weights are computed once per point (``map_coordinates`` per channel recomputed them
        and made 1e6-row temporaries)."""
        xe, ye, d = (np.asarray(a, dtype=float).reshape(-1) for a in (xe, ye, d))
        (x0, y0, d0), (sx, sy, sd) = self.origin, self.step
        nd, ny, nx, k = self.values.shape
        flat = self.values.reshape(-1, k)
        for s in range(0, len(xe), LATTICE_BLOCK):
            part = slice(s, s + LATTICE_BLOCK)
            u = [(d[part] - d0) / sd, (ye[part] - y0) / sy, (xe[part] - x0) / sx]
            inside = np.ones(len(u[0]), bool)
            for c, size in zip(u, (nd, ny, nx), strict=True):
                inside &= (c >= 0) & (c <= size - 1)
            if not inside.any():
                continue
            u = [c[inside] for c in u]
            # the cell below each point (the last cell for a point on the upper face)
            cell = [np.minimum(c.astype(np.intp), max(size - 2, 0))
                    for c, size in zip(u, (nd, ny, nx), strict=True)]  # fmt: skip
            f = [(c - i)[:, None] for c, i in zip(u, cell, strict=True)]
            idx = (cell[0] * ny + cell[1]) * nx + cell[2]
            corner = {}
            for a in (0, 1):
                for b in (0, 1):
                    lo = flat.take(idx + (a * ny + b) * nx, axis=0)
                    hi = flat.take(idx + (a * ny + b) * nx + 1, axis=0)
                    corner[a, b] = lo + (hi - lo) * f[2]
            lo = corner[0, 0] + (corner[0, 1] - corner[0, 0]) * f[1]
            hi = corner[1, 0] + (corner[1, 1] - corner[1, 0]) * f[1]
            yield np.flatnonzero(inside) + s, lo + (hi - lo) * f[0]

    def points(self, xe, ye, d) -> tuple[np.ndarray, np.ndarray]:
        """``(n, 3)`` lon/lat/h and ``(n,)`` height sigmas (m) at epipolar points (NaN where
        :meth:`interpolate` has none)."""
        value = self.interpolate(xe, ye, d)
        return value[:, :3] + self.centre, value[:, 3]


def _metres_per_unit(centre) -> np.ndarray:
    """Metres per degree of longitude and latitude, and per metre of height, at ``centre``
    (a sphere's: for the lattice's check, in metres, of differences of a few 1e-8 degrees)."""
    per_deg = np.pi / 180.0 * 6_378_137.0
    return np.array([per_deg * np.cos(np.radians(centre[1])), per_deg, 1.0])


def _exact(models, matches, method):
    """:func:`triangulate` of ``(n, 2, 2)`` matches in NaN-padded chunks of
    :data:`LATTICE_CHUNK` (one compiled shape): points ``(n, 3)``, height sigmas ``(n,)``."""
    n = len(matches)
    pad = -n % LATTICE_CHUNK
    padded = np.concatenate([matches, np.full((pad, 2, 2), np.nan)])
    ground, result = triangulate(models, padded, method, chunk=LATTICE_CHUNK)
    sigma = np.full(n, np.nan) if result is None else np.asarray(result.sigma_enu)[:n, 2]
    return ground[:n], sigma


def disparity_lattice(
    models: Sequence[AbstractSensorModel],
    grids: EpipolarGrids,
    right_epipolar,
    extent: tuple[int, int, int, int],
    disparity_range: tuple[float, float],
    method: str = "intersect",
) -> DisparityLattice:
    """The :class:`DisparityLattice` of a rectified pair ``models = (left, right)`` over the
    left epipolar columns ``extent[0]..extent[1]``, rows ``extent[2]..extent[3]`` (px) and the
    disparities ``disparity_range`` (px): ``xe`` and ``ye`` nodes those of ``grids`` (every
    ``grids.step_px``), ``d`` nodes every half step; each node's left sensor point through the
    grids, its right one at the right epipolar point ``right_epipolar(xe + d, ye)`` (``(n, 2)``:
    with the vertical disparity's shift), triangulated by :func:`triangulate` (``method``).
    Checked at up to :data:`LATTICE_CHECKS` cell centres (``check_error_m``)."""
    x0, x1, y0, y1 = extent
    step = grids.step_px
    dstep = step / 2.0
    xs = step * np.arange(np.floor(x0 / step), np.ceil(x1 / step) + 1)
    ys = step * np.arange(np.floor(y0 / step), np.ceil(y1 / step) + 1)
    lo, hi = disparity_range
    ds = dstep * np.arange(np.floor(lo / dstep) - 1, np.ceil(hi / dstep) + 2)
    d, y, x = (a.reshape(-1) for a in np.meshgrid(ds, ys, xs, indexing="ij"))
    rng = np.random.default_rng(0)
    cells = (len(ds) - 1) * (len(ys) - 1) * (len(xs) - 1)
    pick = rng.choice(cells, min(LATTICE_CHECKS, cells), replace=False)
    kd, ky, kx = np.unravel_index(pick, (len(ds) - 1, len(ys) - 1, len(xs) - 1))
    cd, cy, cx = ds[kd] + dstep / 2, ys[ky] + step / 2, xs[kx] + step / 2
    ex, ey, ed = np.concatenate([x, cx]), np.concatenate([y, cy]), np.concatenate([d, cd])
    left = grids.to_sensor("left", np.stack([ex, ey], axis=-1))
    right = grids.to_sensor("right", right_epipolar(ex + ed, ey))
    ground, sigma = _exact(models, np.stack([left, right], axis=1), method)
    finite = np.all(np.isfinite(ground), axis=1)
    if not finite.any():
        raise StereoError("stereo: no node of the triangulation lattice triangulates")
    centre = np.median(ground[finite], axis=0)
    # d up / d xy at the nodes and the check points (NaN-padded chunks: one compiled shape)
    up = intersection_jacobian(models, ground, chunk=LATTICE_CHUNK)[:, 2]
    offsets = np.column_stack([ground - centre, sigma, up.reshape(len(ground), -1)])
    n = len(x)
    values = offsets[:n].reshape(len(ds), len(ys), len(xs), offsets.shape[1])
    lattice = DisparityLattice((float(xs[0]), float(ys[0]), float(ds[0])),
                               (float(step), float(step), float(dstep)), centre, values,
                               float("inf"))  # fmt: skip
    got, exact = lattice.interpolate(cx, cy, cd), offsets[n:]
    both = np.all(np.isfinite(got[:, :3]), axis=1) & finite[n:]
    diff = (got[both, :3] - exact[both, :3]) * _metres_per_unit(centre)
    error = float(np.max(np.abs(diff), initial=0.0)) if both.any() else float("inf")
    both &= np.all(np.isfinite(got[:, 4:]), axis=1) & np.all(np.isfinite(exact[:, 4:]), axis=1)
    norm = np.linalg.norm(exact[both, 4:], axis=1)
    rel = np.linalg.norm(got[both, 4:] - exact[both, 4:], axis=1) / norm
    jac_error = float(np.max(rel, initial=0.0)) if both.any() else float("inf")
    return dataclasses.replace(lattice, check_error_m=error, jacobian_check_error=jac_error)


def triangulate_disparities(
    models: Sequence[AbstractSensorModel],
    lattice: DisparityLattice | None,
    epipolar: np.ndarray,
    matches: np.ndarray | Callable[[np.ndarray], np.ndarray],
    method: str = "intersect",
    up_jacobian: bool = False,
) -> tuple[np.ndarray, ...]:
    """Points ``(n, 3)`` and height sigmas ``(n,)`` of dense matches: ``epipolar`` ``(n, 3)``
    their left epipolar ``(xe, ye)`` and disparity, ``matches`` ``(n, 2, 2)`` their left and
    right sensor points, or a function of row indices ``(m,)`` giving those rows' ``(m, 2,
    2)`` (made then only for the points the lattice does not answer: a 1 Mpx tile's matches
    are 32 MB). Interpolated in ``lattice`` when it is usable, triangulated one by one
    (:func:`triangulate`) otherwise and where the lattice has no value.

    ``up_jacobian``: also return the ``(n, 2, 2)`` ``d up / d xy`` of each point for
    :func:`~jaxgeo.stereo._uncertainty.point_height_sigmas`, interpolated in the lattice when
    its check passed (:data:`JACOBIAN_TOL`), NaN elsewhere (computed there per point)."""
    n = len(epipolar)
    if callable(matches):
        matches_of, known = matches, np.all(np.isfinite(epipolar), axis=1)
    else:
        matches_of, known = matches.__getitem__, np.all(np.isfinite(matches), axis=(1, 2))
    # float32: d up / d xy to 1e-7 relative for sigmas, half the bytes of a 1 Mpx tile's array
    none = (np.full((n, 2, 2), np.nan, np.float32),) if up_jacobian else ()
    if n == 0:
        return (np.zeros((0, 3)), np.zeros(0), *none)
    if lattice is None or not lattice.usable:
        return (*_exact(models, matches_of(np.arange(n)), method), *none)
    points, sigma = np.full((n, 3), np.nan), np.full(n, np.nan)
    up = none[0] if up_jacobian and lattice.jacobian_usable else None
    for rows, value in lattice.blocks(epipolar[:, 0], epipolar[:, 1], epipolar[:, 2]):
        points[rows] = value[:, :3] + lattice.centre
        sigma[rows] = value[:, 3]
        if up is not None:
            up[rows] = value[:, 4:].reshape(-1, 2, 2)
    missing = ~np.all(np.isfinite(points), axis=1) & known
    if missing.any():
        points[missing], sigma[missing] = _exact(models, matches_of(np.flatnonzero(missing)),
                                                 method)  # fmt: skip
        if up is not None:
            up[missing] = np.nan
    return (points, sigma, *none)
