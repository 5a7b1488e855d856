"""Initial ground points: given values, GCP coordinates, or forward intersection.

The unknown points start from the user's ``initial`` values, else their GCP coordinates, else a
first-order forward intersection (:func:`jaxgeo.intersect.intersect_linear`, 001_ section 5.5,
method III) with the initial models; the adjustment refines them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ...intersect import intersect_linear
from ...io import Observations
from .._errors import AdjustmentError
from .checks import listing


def initial_points(
    point_ids: Sequence[str],
    start: Mapping[str, Any],
    obs: Observations,
    xy: np.ndarray,
    sig_px: np.ndarray,
    image_models: Mapping[str, Any],
) -> np.ndarray:
    """``(n_points, 3)`` initial ``(lon_deg, lat_deg, h_m)`` of every point, in ``point_ids``
    order: ``start[id]`` where given (the user's initial values, else the GCP coordinates),
    else intersected (see the module docstring); raises naming the points that cannot be
    intersected."""
    origin = np.full((len(point_ids), 3), np.nan)
    for j, pid in enumerate(point_ids):
        if pid in start:
            origin[j] = np.asarray(start[pid], dtype=float)
    todo = [j for j in range(len(point_ids)) if not np.all(np.isfinite(origin[j]))]
    intersect_points(todo, point_ids, obs, xy, sig_px, image_models, origin)
    return origin


def intersect_points(
    todo: Sequence[int],
    point_ids: Sequence[str],
    obs: Observations,
    xy: np.ndarray,
    sig_px: np.ndarray,
    image_models: Mapping[str, Any],
    origin: np.ndarray,
) -> None:
    """Initial values of tie/check points: first-order forward intersection with the initial
    models (001_ section 5.5, method III), one batch per set of images (so a strip's pairs do
    not evaluate every model of the strip); the adjustment refines them."""
    rows: dict[str, list[int]] = {}
    for i, pid in enumerate(obs.point_ids):
        rows.setdefault(pid, []).append(i)
    # every point is intersected (GCPs too, then discarded): the batch shapes, hence the
    # compiled intersection, do not depend on the roles of the points
    need = set(todo)
    by_images: dict[tuple[str, ...], list[int]] = {}
    for j in range(len(point_ids)):
        imgs = tuple(sorted(obs.images[i] for i in rows[point_ids[j]]))
        by_images.setdefault(imgs, []).append(j)
    for imgs, members in by_images.items():
        col = {name: c for c, name in enumerate(imgs)}
        pts = np.full((len(members), len(imgs), 2), np.nan)
        sig = np.ones((len(members), len(imgs)))
        for r, j in enumerate(members):
            for i in rows[point_ids[j]]:
                pts[r, col[obs.images[i]]] = xy[i]
                sig[r, col[obs.images[i]]] = sig_px[i]
        if not need.intersection(members):
            continue
        ground = np.asarray(intersect_linear([image_models[n] for n in imgs], pts, sig))
        bad = [
            point_ids[j]
            for r, j in enumerate(members)
            if j in need and not np.all(np.isfinite(ground[r]))
        ]
        if bad:
            raise AdjustmentError(
                f"point(s) {listing(bad)} could not be intersected from images {listing(imgs)} "
                "with the initial models (rays nearly parallel, or far outside the models' domain)"
            )
        for r, j in enumerate(members):
            if j in need:
                origin[j] = ground[r]
