"""Checks of the user's input, before any array is built: every message names the image, point
or parameter at fault (:class:`~jaxgeo.bundle.errors.AdjustmentError`)."""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from jaxtyping import PyTree

from ...geodesy import metres_per_unit
from ...io.tables import GroundPoints, Observations
from ...models.base import AbstractMultiImageModel, AbstractSensorModel
from ...models.affine3d import COPLANAR_RTOL, Affine3D
from ..errors import AdjustmentError, TooFewControlPoints


def image_names(key: Any) -> tuple[str, ...]:
    """The image names of a model key (one name, or a tuple for a multi-image model)."""
    return (key,) if isinstance(key, str) else tuple(key)


def label(key: Any) -> str:
    """A model key as written in messages and parameter names: ``left`` or ``(fore, aft)``."""
    return key if isinstance(key, str) else "(" + ", ".join(key) + ")"


def listing(items, limit: int = 10) -> str:
    """``'a', 'b' and 3 more``: at most ``limit`` items quoted."""
    items = list(items)
    more = f" and {len(items) - limit} more" if len(items) > limit else ""
    return ", ".join(repr(i) for i in items[:limit]) + more


def check_models(models: Mapping[Any, Any]) -> dict[str, tuple[Any, int]]:
    """Image name -> ``(model key, slot)``; refuses empty, repeated or malformed names and models
    of the wrong kind (a multi-image model under a tuple key, a sensor model under a name)."""
    if not models:
        raise AdjustmentError("no models given")
    image_of: dict[str, tuple[Any, int]] = {}
    for key, model in models.items():
        for slot, name in enumerate(image_names(key)):
            if not isinstance(name, str) or not name:
                raise AdjustmentError(f"image names must be non-empty strings, got {name!r}")
            if name in image_of:
                raise AdjustmentError(f"image {name!r} is given twice")
            image_of[name] = (key, slot)
        if isinstance(key, str):
            if not isinstance(model, AbstractSensorModel):
                raise AdjustmentError(
                    f"{label(key)}: expected a sensor model (AbstractSensorModel), got "
                    f"{type(model).__name__}"
                )
        elif not isinstance(model, AbstractMultiImageModel):
            raise AdjustmentError(
                f"{label(key)}: a model for several images must be a multi-image model "
                f"(AbstractMultiImageModel, with an image(i) method), got {type(model).__name__}"
            )
    return image_of


def check_observations(
    obs: Observations, images: Mapping[str, Any], xy: np.ndarray, sigma_px: np.ndarray
) -> None:
    """Every observation names a known image and has finite coordinates and a positive sigma."""
    for i, (pid, img) in enumerate(zip(obs.point_ids, obs.images, strict=True)):
        if img not in images:
            raise AdjustmentError(
                f"observation {i} of point {pid!r} names unknown image {img!r} "
                f"(images: {listing(images)})"
            )
        if not (np.all(np.isfinite(xy[i])) and np.isfinite(sigma_px[i]) and sigma_px[i] > 0):
            raise AdjustmentError(
                f"observation {i} of point {pid!r} in image {img!r} has a non-finite coordinate "
                f"or a non-positive sigma: x, y = {xy[i].tolist()}, sigma = {sigma_px[i]}"
            )


def check_ground(ground: GroundPoints, lonlath: np.ndarray) -> None:
    """Every ground point has finite coordinates and positive (or infinite) sigmas."""
    for i, pid in enumerate(ground.ids):
        if not np.all(np.isfinite(lonlath[i])):
            raise AdjustmentError(f"ground point {pid!r} has non-finite coordinates {lonlath[i]}")
        if np.any(~(np.asarray(ground.sigma_m[i]) > 0)):
            raise AdjustmentError(f"ground point {pid!r} has a non-positive or NaN sigma")


def check_points(
    obs: Observations,
    ground: GroundPoints,
    point_ids: Sequence[str],
    role: Sequence[str],
    initial: Mapping[str, Any],
) -> None:
    """Warns about ground points measured nowhere; refuses points seen in one image only that
    have neither ground coordinates nor an initial value (they cannot be determined)."""
    measured = set(point_ids)
    unmeasured = [p for p in ground.ids if p not in measured]
    if unmeasured:
        warnings.warn(
            f"ground point(s) {listing(unmeasured)} are not measured in any image: ignored",
            stacklevel=4,
        )
    images_of_point: dict[str, list[str]] = {p: [] for p in point_ids}
    for pid, img in zip(obs.point_ids, obs.images, strict=True):
        images_of_point[pid].append(img)
    lonely = [
        p
        for p, r in zip(point_ids, role, strict=True)
        if r != "gcp" and len(images_of_point[p]) < 2 and p not in initial
    ]
    if lonely:
        raise AdjustmentError(
            f"point(s) {listing(lonely)} are seen in one image only and have no ground "
            f"coordinates (image {images_of_point[lonely[0]][0]!r}): they cannot be determined; "
            "measure them in a second image, give them as GCPs, or remove them"
        )


def coplanar(lonlath: np.ndarray) -> bool:
    """Whether ground points are (near-)coplanar in local metres (``COPLANAR_RTOL``)."""
    centre = lonlath.mean(axis=0)
    metric = (lonlath - centre) * metres_per_unit(centre, xp=np)
    sv = np.linalg.svd(metric, compute_uv=False)
    return not (sv[0] > 0 and sv[-1] / sv[0] >= COPLANAR_RTOL)


def check_control(
    block_of: Mapping[str, Any],
    dynamic: Mapping[str, PyTree],
    obs: Observations,
    ground: GroundPoints,
    lonlath: np.ndarray,
) -> None:
    """Every image has the GCPs its adjustable parameters need (the model's
    ``required_gcps``), non-coplanar for the 3D affine model.

    ``block_of``: image name -> the model (block) that serves it; ``dynamic``: image name ->
    the adjusted part of that block.
    """
    gindex = {pid: i for i, pid in enumerate(ground.ids)}
    for name, model in block_of.items():
        need = model.required_gcps(dynamic[name])
        if need is None:
            continue
        n, what = need
        gcps = sorted(
            {
                p
                for p, img in zip(obs.point_ids, obs.images, strict=True)
                if img == name and p in gindex and ground.role[gindex[p]] == "gcp"
            }
        )
        if len(gcps) < n:
            raise TooFewControlPoints(
                f"image {name!r}: {what} needs at least {n} GCP(s) measured in the image, "
                f"got {len(gcps)}" + (f" ({listing(gcps)})" if gcps else "")
            )
        # the one model whose GCPs must also span three dimensions
        if isinstance(model, Affine3D) and coplanar(lonlath[[gindex[p] for p in gcps]]):
            raise TooFewControlPoints(
                f"image {name!r}: the GCPs {listing(gcps)} are (near-)coplanar; the 3D affine "
                "model needs at least 4 non-coplanar GCPs"
            )
