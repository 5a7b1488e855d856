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

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import JaxgeoError
from ..geodesy import ecef_to_geodetic, geodetic_to_ecef
from ..intersect import IntersectResult, intersect
from ..models import AbstractSensorModel
from ._rectification import EpipolarGrids

VALIDITY_MARGIN = 0.1
"""How far past its RPC's validity cube a 3D point still counts as inside, in cube half-widths
(most points outside: the model does not fit the images)."""
BLUNDER_MARGIN = 0.5
"""How far past the validity cube a single 3D point is dropped as a blunder (half-widths)."""


class StereoError(JaxgeoError, ValueError):
    """A stereo pair jaxgeo refuses: the message names the images and what does not fit (an ROI
    the other image does not see, tie points or 3D points outside the models' validity, an
    offset across the epipolar lines larger than any relative bias)."""


def outside_validity(
    points: np.ndarray, model: AbstractSensorModel, margin: float = VALIDITY_MARGIN
) -> np.ndarray:
    """``(n,)`` True where a finite lon/lat/h point lies outside ``model``'s RPC validity cube
    widened by ``margin`` half-widths (never for a model without an RPC)."""
    points = np.asarray(points, dtype=float)
    rpc = model.base_rpc()
    finite = np.all(np.isfinite(points), axis=-1)
    if rpc is None:
        return np.zeros(points.shape[:-1], bool)
    offset = np.asarray(rpc.ground_offset, dtype=float)
    scale = np.abs(np.asarray(rpc.ground_scale, dtype=float))
    normalised = np.abs(points - offset) / scale
    return finite & np.any(normalised > 1.0 + margin, axis=-1)


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


def _refuse_outside(points, models, paths, what):
    """:class:`StereoError` when most of the finite ``points`` lie outside the validity cube of
    one or both models (named with their images)."""
    finite = np.all(np.isfinite(points), axis=1)
    n = int(finite.sum())
    counts = [int(outside_validity(points, m).sum()) for m in models]
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
    _refuse_outside(points, models, paths, "3D points")
    outside = np.logical_or.reduce([outside_validity(points, m, BLUNDER_MARGIN) for m in models])
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
