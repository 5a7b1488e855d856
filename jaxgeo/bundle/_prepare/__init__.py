"""Build: from user input (models, GROUND/OBS tables) to an array :class:`jaxgeo.lsq.Problem`.

Everything that can be wrong with the input is found here, before any solving, and raised as an
:class:`~jaxgeo.bundle.AdjustmentError` naming the image, point or parameter at fault
(:mod:`.checks`); the models are partitioned and stacked into groups (:mod:`.grouping`), the
ground points get initial values (:mod:`.points`) and the blocks their priors (:mod:`.priors`);
jitter splines get their knots, and their priors are stated (:mod:`.jitter`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ..._runtime.arrays import device_array
from ...geodesy import metres_per_unit
from ...io import GroundPoints, Observations
from ...lsq import GroundObs, ImageObs, ModelGroup, Problem, make_structure
from ...models import Biased
from .._errors import AdjustmentError
from .._settings import DEFAULT_SETTINGS, AdjustSettings
from .checks import (
    Sources,
    check_distinct,
    check_domains,
    check_duplicates,
    check_ground,
    check_models,
    check_observations,
    check_points,
    image_names,
    label,
    listing,
)
from .checks import check_control as check_control_points
from .grouping import make_group, partition_block, per_key, shared_leaves, signature
from .jitter import place_knots, regrid_sigma
from .points import initial_points
from .priors import prior_arrays

ROLES = ("gcp", "check", "tie")
PADDING = 2.0
"""An image slot's observations are sorted by block (``ImageObs.block_start``) when padding
every block to the largest one's count costs at most this factor in evaluations: each block's
model then projects its own observations, vmapped over the blocks, instead of a copy of the
model per observation (an RPC's 80 coefficients: 0.27 s against 0.015 s for 200 000
observations of two RPCs). Very unequal blocks keep the per-observation copies."""


@dataclasses.dataclass(frozen=True)
class Prepared:
    """A :class:`Problem` and the names that map its arrays back to the user's input.

    ``labels``: per group, per block, the user's key (image name or tuple of names);
    ``image_index``: image name -> (group, block, slot); ``point_ids``/``point_role``: per point;
    ``obs_order``: problem observation -> index in the user's :class:`Observations`;
    ``ground_ids``: per ground observation (GCPs, and check points with weight 0), its point id;
    ``param_names``: per raveled parameter; ``notes``: what was chosen and assumed, for the
    report (the jitter splines' knots and priors).
    """

    problem: Problem
    labels: tuple[tuple[Any, ...], ...]
    image_index: dict[str, tuple[int, int, int]]
    point_ids: tuple[str, ...]
    point_role: tuple[str, ...]
    obs_order: np.ndarray
    ground_ids: tuple[str, ...]
    param_names: tuple[str, ...]
    notes: tuple[str, ...] = ()

    def image_models(self, groups: tuple[ModelGroup, ...], theta) -> dict[str, Any]:
        """Image name -> sensor model with parameters ``theta`` (per group)."""
        out = {}
        for name, (g, k, slot) in self.image_index.items():
            block = groups[g].block_at(theta[g], k)
            out[name] = groups[g].image_model(block, slot)
        return out

    def blocks(self, groups: tuple[ModelGroup, ...], theta) -> dict[Any, Any]:
        """User key -> (adjusted) block."""
        return {
            label: groups[g].block_at(theta[g], k)
            for g, labels in enumerate(self.labels)
            for k, label in enumerate(labels)
        }


def prepare(
    models: Mapping[Any, Any],
    observations: Observations,
    ground: GroundPoints | None = None,
    *,
    prior_sigma: Any = None,
    settings: AdjustSettings = DEFAULT_SETTINGS,
    check_control: bool = True,
) -> Prepared:
    """Check the input and build the array problem (arguments as :func:`jaxgeo.adjust`;
    ``check_control``: check every image's GCP count against its adjustable parameters). From
    ``settings`` (:class:`~jaxgeo.bundle.AdjustSettings`): ``filters``, ``initial`` points,
    ``sources`` (the files and lines of the tables, named in messages), ``tie_height``
    (heights ``f(lonlat (n, 2)) -> (n,)`` m, e.g. a :class:`~jaxgeo.io.DEM`, given to every tie
    point as a height observation of sigma ``tie_height_sigma_m``) and ``image_domains`` (image
    name -> ``(x_min, y_min, x_max, y_max)`` px of its raster, bounding its measurements, e.g.
    :meth:`jaxgeo.io.SensorImage.domain`; images without one are bounded by their RPC's image
    domain); its bias priors and jitter are :func:`jaxgeo.adjust`'s."""
    filters, sources, image_domains = settings.filters, settings.sources, settings.image_domains
    tie_height, tie_height_sigma_m = settings.tie_height, settings.tie_height_sigma_m
    initial = settings.initial
    src = sources if sources is not None else Sources()
    image_of = check_models(models)
    models, placed, notes = place_knots(models, observations)
    if placed and isinstance(prior_sigma, Mapping | Biased):  # given for the placeholders
        prior_sigma = {
            k: regrid_sigma(per_key(prior_sigma, k), k, placed[k])
            if k in placed
            else per_key(prior_sigma, k)
            for k in models
        }
    ground = (
        ground if ground is not None else GroundPoints((), np.zeros((0, 3)), (), np.zeros((0, 3)))
    )
    initial = dict(initial or {})

    # --- blocks, filters, groups --------------------------------------------------------
    keys = list(models)
    parts = {
        key: partition_block(models[key], per_key(filters, key), f"model {label(key)}")
        for key in keys
    }
    clashes = shared_leaves([parts[k] for k in keys], [label(k) for k in keys])
    if clashes:
        raise AdjustmentError(
            f"models {clashes[0]} share adjustable parameters (the same arrays): give them as one "
            "multi-image model under a tuple of image names, e.g. {('fore', 'aft'): sequence}"
        )
    by_sig: dict[Any, list] = {}
    for key in keys:
        sig = (isinstance(key, tuple), signature(*parts[key], len(image_names(key))))
        by_sig.setdefault(sig, []).append(key)
    groups, labels, block_at = [], [], {}
    for (multi, _), members in by_sig.items():
        g = len(groups)
        groups.append(
            make_group([parts[k] for k in members], [image_names(k) for k in members], multi)
        )
        labels.append(tuple(members))
        for k, key in enumerate(members):
            block_at[key] = (g, k)
    image_index = {name: (*block_at[key], slot) for name, (key, slot) in image_of.items()}

    # --- observations, ground, points -------------------------------------------------------
    obs = observations
    xy = np.asarray(obs.xy, dtype=float)
    sig_px = np.asarray(obs.sigma_px, dtype=float)
    check_observations(obs, image_index, xy, sig_px)
    lonlath = np.asarray(ground.lonlath, dtype=float)
    check_ground(ground, lonlath)
    check_duplicates(obs, ground, src)
    gindex = {pid: i for i, pid in enumerate(ground.ids)}
    point_ids = list(dict.fromkeys(obs.point_ids))
    pindex = {pid: j for j, pid in enumerate(point_ids)}
    role = [ground.role[gindex[p]] if p in gindex else "tie" for p in point_ids]
    check_points(obs, ground, point_ids, role, initial)
    if check_control:
        block_of = {name: models[key] for name, (key, _) in image_of.items()}
        dynamic = {name: parts[key][0] for name, (key, _) in image_of.items()}
        check_control_points(block_of, dynamic, obs, ground, lonlath)
    image_models = {
        name: groups[g].image_model(groups[g].block_at(groups[g].theta0, k), slot)
        for name, (g, k, slot) in image_index.items()
    }
    check_distinct(image_models)
    check_domains(image_models, obs, ground, lonlath, src, image_domains)
    start = {p: lonlath[gindex[p]] for p, r in zip(point_ids, role, strict=True) if r == "gcp"}
    start.update(initial)  # the user's values first
    origin = initial_points(point_ids, start, obs, xy, sig_px, image_models)

    # --- arrays ---------------------------------------------------------------------------
    obs_img = np.array([image_index[img] for img in obs.images], dtype=np.int64).reshape(-1, 3)
    obs_pt = np.array([pindex[p] for p in obs.point_ids], dtype=np.int64)
    images, order = [], []
    for g in range(len(groups)):
        for slot in range(groups[g].n_slots):
            sel = np.flatnonzero((obs_img[:, 0] == g) & (obs_img[:, 2] == slot))
            if sel.size == 0:
                continue
            start: tuple[int, ...] = ()
            counts = np.bincount(obs_img[sel, 1], minlength=groups[g].n_blocks)
            if counts.size * counts.max() <= PADDING * sel.size:  # sorted by block
                sel = sel[np.argsort(obs_img[sel, 1], kind="stable")]
                start = tuple(int(x) for x in np.concatenate([[0], np.cumsum(counts)]))
            order.append(sel)
            images.append(
                ImageObs(
                    block=device_array(obs_img[sel, 1]),
                    point=device_array(obs_pt[sel]),
                    xy=device_array(xy[sel]),
                    weight=device_array(1.0 / sig_px[sel]),
                    group=g,
                    slot=slot,
                    block_start=start,
                )
            )
    # every point with ground coordinates gets a ground observation, with weight 0 for check
    # points: the arrays, hence the compiled solve, do not depend on which points are GCPs
    known = [p for p, r in zip(point_ids, role, strict=True) if r in ("gcp", "check")]
    gsig = np.asarray([ground.sigma_m[gindex[p]] for p in known], dtype=float).reshape(-1, 3)
    is_gcp = np.array([ground.role[gindex[p]] == "gcp" for p in known], dtype=bool)
    gweight = np.where(np.isfinite(gsig) & is_gcp.reshape(-1, 1), 1.0 / gsig, 0.0)
    g_point = np.array([pindex[p] for p in known], dtype=np.int64)
    g_lonlath = lonlath[[gindex[p] for p in known]].reshape(-1, 3)
    gweight = gweight.reshape(-1, 3)
    if tie_height is not None:  # tie heights as observations: up only, at the initial lon/lat
        ties = [j for j, r in enumerate(role) if r == "tie"]
        h = dem_heights(tie_height, origin[ties, :2], [point_ids[j] for j in ties])
        known = known + [point_ids[j] for j in ties]
        g_point = np.concatenate([g_point, np.asarray(ties, dtype=np.int64)])
        g_lonlath = np.concatenate([g_lonlath, np.column_stack([origin[ties, :2], h])])
        up = np.tile([0.0, 0.0, 1.0 / _positive_sigma(tie_height_sigma_m)], (len(ties), 1))
        gweight = np.concatenate([gweight, up])
    gobs = GroundObs(
        point=device_array(g_point),
        lonlath=device_array(g_lonlath.reshape(-1, 3)),
        weight=device_array(gweight.reshape(-1, 3)),
    )
    prior_mean, prior_weight, n_prior_rows = prior_arrays(
        groups, labels, models, filters, prior_sigma
    )
    n_rows = 2 * len(obs.point_ids) + int(np.count_nonzero(np.asarray(gobs.weight))) + n_prior_rows
    groups_t, images_t = tuple(groups), tuple(images)
    problem = Problem(
        groups=groups_t,
        images=images_t,
        ground=gobs,
        origin=device_array(origin),
        metres_per_unit=device_array(metres_per_unit(origin, xp=np)),
        prior_mean=prior_mean,
        prior_weight=prior_weight,
        structure=make_structure(groups_t, images_t, gobs, len(point_ids)),
        n_rows=device_array(n_rows),
    )
    param_names = tuple(
        f"{label(key)}{name}"
        for g, grp in enumerate(groups)
        for key in labels[g]
        for name in grp.param_names
    )
    return Prepared(
        problem=problem,
        labels=tuple(labels),
        image_index=image_index,
        point_ids=tuple(point_ids),
        point_role=tuple(role),
        obs_order=np.concatenate(order) if order else np.zeros(0, dtype=np.int64),
        ground_ids=tuple(known),
        param_names=param_names,
        notes=notes,
    )


def _positive_sigma(sigma: float) -> float:
    if not (np.isfinite(sigma) and sigma > 0):
        raise AdjustmentError(f"the tie height sigma must be a positive number, got {sigma!r}")
    return float(sigma)


def dem_heights(
    tie_height: Callable[[np.ndarray], np.ndarray], lonlat: np.ndarray, ids: list[str]
) -> np.ndarray:
    """``tie_height(lonlat)`` (m), refused naming the points where it is not finite (or the
    DEM's own message, e.g. a point outside it)."""
    try:
        h = np.asarray(tie_height(np.asarray(lonlat, dtype=float)), dtype=float).reshape(-1)
    except ValueError as err:
        raise AdjustmentError(f"tie heights from the DEM: {err}") from None
    if h.shape != (len(ids),):
        raise AdjustmentError(f"the tie height function returned {h.shape} values for "
                              f"{len(ids)} tie points")  # fmt: skip
    bad = [p for p, v in zip(ids, h, strict=True) if not np.isfinite(v)]
    if bad:
        raise AdjustmentError(f"no DEM height for tie point(s) {listing(bad)} (outside the DEM "
                              "or on nodata)")  # fmt: skip
    return h
