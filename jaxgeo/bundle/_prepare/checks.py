"""Checks of the user's input, before any array is built: every message names the image, point
or parameter at fault (:class:`~jaxgeo.bundle.AdjustmentError`)."""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from jaxtyping import PyTree

from ...errors import JaxgeoWarning
from ...geodesy import metres_per_unit
from ...io import GroundPoints, Observations
from ...models import AbstractMultiImageModel, AbstractSensorModel, Affine3D
from ...models.internal import COPLANAR_RTOL
from .._errors import AdjustmentError, TooFewControlPoints


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
    names = np.asarray(obs.images, dtype=object)
    known = np.isin(names, np.asarray(list(images), dtype=object)) if len(names) else names
    ok = np.all(np.isfinite(xy), axis=1) & np.isfinite(sigma_px) & (sigma_px > 0) & known
    for i in np.flatnonzero(~ok).tolist():  # the messages, for the (few) observations at fault
        pid, img = obs.point_ids[i], obs.images[i]
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
            JaxgeoWarning,
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


DOMAIN_TOLERANCE = 1.5
"""A ground point whose normalised RPC coordinate exceeds this (1 = the edge of the validity
cube) is refused: RPCs extrapolate wildly outside their fitting cube."""
IMAGE_MARGIN = 0.02
"""Without the image's size, measurements may lie this fraction of the RPC's image domain
(offset +- scale, plus one pixel) outside it."""
RASTER_MARGIN_PX = 0.5
"""With the image's size (its raster), measurements may lie this far (px) beyond the outer
pixel edges (``-0.5 .. width - 0.5``): sub-pixel measurements on the border."""


@dataclasses.dataclass(frozen=True)
class Sources:
    """Where the tables came from, for messages: the files and the line of each row."""

    observations: str | None = None
    observation_lines: Sequence[int] | np.ndarray = ()
    ground: str | None = None
    ground_lines: Sequence[int] | np.ndarray = ()

    def obs(self, i: int) -> str:
        if self.observations and i < len(self.observation_lines):
            return f"{self.observations}:{self.observation_lines[i]}: observation {i}"
        return f"observation {i}"

    def point(self, i: int) -> str:
        if self.ground and i < len(self.ground_lines):
            return f"{self.ground}:{self.ground_lines[i]}: ground point"
        return "ground point"


def check_duplicates(obs: Observations, ground: GroundPoints, src: Sources = Sources()) -> None:
    """The same point twice in one image (contradictory when the coordinates differ), or the
    same ground point id twice."""
    first: dict[tuple[str, str], int] = {}
    for i, key in enumerate(zip(obs.point_ids, obs.images, strict=True)):
        if key in first:
            j = first[key]
            same = np.allclose(obs.xy[i], obs.xy[j])
            what = "duplicate" if same else (
                f"contradictory: x, y = {obs.xy[j].tolist()} and {obs.xy[i].tolist()}"
            )  # fmt: skip
            raise AdjustmentError(
                f"{src.obs(i)}: point {key[0]!r} is measured twice in image {key[1]!r} "
                f"(also {src.obs(j)}; {what})"
            )
        first[key] = i
    seen: dict[str, int] = {}
    for i, pid in enumerate(ground.ids):
        if pid in seen:
            raise AdjustmentError(
                f"{src.point(i)} {pid!r} is given twice (also {src.point(seen[pid])}): "
                f"{ground.lonlath[seen[pid]].tolist()} and {ground.lonlath[i].tolist()}"
            )
        seen[pid] = i


def _image_box(rpc, domain):
    """``(lo (2,), hi (2,), margin (2,), what)`` of the measurements allowed in an image: its
    raster's extent (``domain``, :meth:`jaxgeo.io.SensorImage.domain`) when known, else its
    RPC's image domain; ``None`` without either."""
    if domain is not None:
        x0, y0, x1, y1 = (float(v) for v in domain)
        lo, hi = np.array([x0, y0]), np.array([x1, y1])
        if np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)):
            w, h = hi - lo
            return lo, hi, np.full(2, RASTER_MARGIN_PX), f"its raster, {w:.0f} x {h:.0f} px"
    if rpc is None:
        return None
    ioff, iscale = np.asarray(rpc.image_offset, float), np.abs(np.asarray(rpc.image_scale, float))
    what = "from its RPC's image offset +- scale; give the image raster to check its size"
    return ioff - iscale, ioff + iscale, iscale * IMAGE_MARGIN + 1.0, what


def check_domains(
    image_models: Mapping[str, Any],
    obs: Observations,
    ground: GroundPoints,
    lonlath: np.ndarray,
    src: Sources = Sources(),
    domains: Mapping[str, Sequence[float]] | None = None,
) -> None:
    """Ground points (GCPs, check points) measured in an image lie inside (within
    ``DOMAIN_TOLERANCE``) the validity cube of its RPC, and every measurement inside the image:
    its raster's extent when ``domains`` gives it (``(x_min, y_min, x_max, y_max)`` px per
    image name, within ``RASTER_MARGIN_PX``), else the RPC's image domain (within
    ``IMAGE_MARGIN``); the messages say by how much."""
    domains = dict(domains or {})
    gindex = {pid: i for i, pid in enumerate(ground.ids)}
    frames = {name: m.base_rpc() for name, m in image_models.items()}
    boxes = {name: _image_box(frames[name], domains.get(name)) for name in image_models}
    axes = (("longitude", "deg"), ("latitude", "deg"), ("height", "m"))
    # vectorised per image; the messages below for the (few) observations at fault
    xy = np.asarray(obs.xy, dtype=float).reshape(-1, 2)
    names = np.asarray(obs.images, dtype=object)
    gk = np.array([gindex.get(p, -1) for p in obs.point_ids], dtype=np.int64)
    suspect = np.zeros(len(names), dtype=bool)
    for name in image_models:
        sel = np.flatnonzero(names == name)
        if sel.size == 0:
            continue
        bad = np.zeros(sel.size, dtype=bool)
        box = boxes[name]
        if box is not None:
            lo, hi, margin, _ = box
            bad |= np.any((xy[sel] < lo - margin) | (xy[sel] > hi + margin), axis=1)
        rpc = frames[name]
        has_g = gk[sel] >= 0
        if rpc is not None and np.any(has_g):
            goff = np.asarray(rpc.ground_offset, float)
            gscale = np.asarray(rpc.ground_scale, float)
            norm = np.abs(lonlath[gk[sel][has_g]] - goff) / gscale
            bad[np.flatnonzero(has_g)] |= np.any(norm > DOMAIN_TOLERANCE, axis=1)
        suspect[sel[bad]] = True
    for i in np.flatnonzero(suspect).tolist():
        pid, img = obs.point_ids[i], obs.images[i]
        box = boxes.get(img)
        if box is not None:
            lo, hi, margin, what = box
            beyond = np.maximum(lo - obs.xy[i], obs.xy[i] - hi)
            if np.any(beyond > margin):
                role = ground.role[gindex[pid]] if pid in gindex else "tie"
                raise AdjustmentError(
                    f"{src.obs(i)}: point {pid!r} ({role}) at x, y = {obs.xy[i].tolist()} lies "
                    f"{float(np.max(beyond)):.0f} px outside image {img!r} (x {lo[0]:.1f}.."
                    f"{hi[0]:.1f}, y {lo[1]:.1f}..{hi[1]:.1f} px: {what})"
                )
        rpc = frames.get(img)
        k = gindex.get(pid)
        if k is None or rpc is None:
            continue
        goff, gscale = np.asarray(rpc.ground_offset, float), np.asarray(rpc.ground_scale, float)
        norm = np.abs(lonlath[k] - goff) / gscale
        if np.any(norm > DOMAIN_TOLERANCE):
            a = int(np.argmax(norm))
            name, unit = axes[a]
            out = abs(lonlath[k, a] - goff[a]) - gscale[a]
            raise AdjustmentError(
                f"{src.point(k)} {pid!r} ({ground.role[k]}) lies outside the validity domain of "
                f"the RPC of image {img!r}: its {name} {lonlath[k, a]:.6g} {unit} is {out:.4g} "
                f"{unit} beyond {goff[a] - gscale[a]:.6g}..{goff[a] + gscale[a]:.6g} {unit} "
                "(check its coordinates, or the image it is measured in)"
            )


def check_distinct(image_models: Mapping[str, Any]) -> None:
    """No two images have the same RPC (the same file given for two images, or a model given
    for the wrong image): their rays would be parallel."""
    seen: dict[bytes, str] = {}
    for name, model in image_models.items():
        rpc = model.base_rpc()
        if rpc is None:
            continue
        leaves = (rpc.num, rpc.den, rpc.ground_offset, rpc.image_offset)
        key = b"".join(np.asarray(leaf, float).tobytes() for leaf in leaves)
        if key in seen:
            raise AdjustmentError(
                f"images {seen[key]!r} and {name!r} have the same RPC: one of them is given the "
                "other's model (check which model file goes with which image)"
            )
        seen[key] = name
