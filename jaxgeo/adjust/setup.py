"""From user input (models, GROUND/OBS tables) to an array :class:`~.problem.Problem`, with checks.

Everything that can be wrong with the input is found here, before any solving, and raised as an
:class:`~.errors.AdjustmentError` naming the image, point or parameter at fault: unknown image
names, NaNs, points seen in one image only without ground coordinates, too few GCPs for the
adjustable parameters of an image, shared parameters given as separate models.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..intersect import intersect_linear
from ..io.tables import GroundPoints, Observations
from ..models import Biased
from ..models.affine3d import COPLANAR_RTOL, Affine3D
from .core import block_priors
from .errors import AdjustmentError, TooFewControlPoints
from .params import ModelGroup, make_group, partition_block, ravel_stacked, shared_leaves, signature
from .problem import LOSSES, GroundObs, ImageObs, Problem, make_structure, metres_per_unit_np

ROLES = ("gcp", "check", "tie")


@dataclasses.dataclass(frozen=True)
class Setup:
    """A :class:`Problem` and the names that map its arrays back to the user's input.

    ``labels``: per group, per block, the user's key (image name or tuple of names);
    ``image_index``: image name -> (group, block, slot); ``point_ids``/``point_role``: per point;
    ``obs_order``: problem observation -> index in the user's :class:`Observations`;
    ``ground_ids``: per ground observation (GCPs, and check points with weight 0), its point id;
    ``param_names``: per raveled parameter.
    """

    problem: Problem
    labels: tuple[tuple[Any, ...], ...]
    image_index: dict[str, tuple[int, int, int]]
    point_ids: tuple[str, ...]
    point_role: tuple[str, ...]
    obs_order: np.ndarray
    ground_ids: tuple[str, ...]
    param_names: tuple[str, ...]

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


def _names(key) -> tuple[str, ...]:
    return (key,) if isinstance(key, str) else tuple(key)


def _label(key) -> str:
    return key if isinstance(key, str) else "(" + ", ".join(key) + ")"


def _list(items, limit: int = 10) -> str:
    items = list(items)
    more = f" and {len(items) - limit} more" if len(items) > limit else ""
    return ", ".join(repr(i) for i in items[:limit]) + more


def _per_key(value, key, default=None):
    """A per-model option given once for all models or as a mapping keyed by model key."""
    if isinstance(value, Mapping):
        return value.get(key, default)
    return default if value is None else value


def required_gcps(block, dynamic) -> tuple[int, str] | None:
    """``(n, what)``: GCPs an image of this block needs for its adjustable parameters."""
    if isinstance(block, Biased) and jax.tree.leaves(dynamic.bias):
        n = block.bias.n_params // 2
        return n, f"the {type(block.bias).__name__} bias ({block.bias.n_params} parameters)"
    if isinstance(block, Affine3D) and jax.tree.leaves(dynamic):
        return 4, "the 3D affine model (8 parameters, non-coplanar GCPs)"
    return None


def _coplanar(lonlath: np.ndarray) -> bool:
    centre = lonlath.mean(axis=0)
    metric = (lonlath - centre) * metres_per_unit_np(centre)
    sv = np.linalg.svd(metric, compute_uv=False)
    return not (sv[0] > 0 and sv[-1] / sv[0] >= COPLANAR_RTOL)


def _prior(sigma, dynamic_shapes_n, key, partition) -> tuple[np.ndarray, np.ndarray] | None:
    """Raveled ``(mean, weight)`` of a parameter prior (``sigma``: scalar, array or pytree)."""
    if sigma is None:
        return None
    theta0, p = dynamic_shapes_n
    if np.ndim(sigma) == 0 and not hasattr(sigma, "__dataclass_fields__"):
        sig = np.full(p, float(sigma))
    elif isinstance(sigma, np.ndarray | jax.Array | list | tuple) and np.size(sigma) == p:
        sig = np.asarray(sigma, dtype=float).reshape(p)
    else:
        dyn, _ = partition(sigma)
        sig = ravel_stacked([np.asarray(x)[None] for x in jax.tree.leaves(dyn)], 1)[0]
    if sig.shape != (p,) or np.any(~(sig > 0)):
        raise AdjustmentError(
            f"{_label(key)}: prior sigma must be positive, one per adjustable parameter ({p})"
        )
    weight = np.where(np.isfinite(sig), 1.0 / sig, 0.0)
    return np.asarray(theta0, dtype=float), weight


def build(
    models: Mapping[Any, Any],
    observations: Observations,
    ground: GroundPoints | None = None,
    *,
    filters: Any = None,
    prior_sigma: Any = None,
    initial: Mapping[str, Any] | None = None,
    loss: str = "l2",
    loss_scale: float = 3.0,
    check_control: bool = True,
) -> Setup:
    """Check the input and build the array problem (see :func:`jaxgeo.adjust.adjust`)."""
    if loss not in LOSSES:
        raise AdjustmentError(f"loss must be one of {LOSSES}, got {loss!r}")
    if not models:
        raise AdjustmentError("no models given")
    ground = (
        ground if ground is not None else GroundPoints((), np.zeros((0, 3)), (), np.zeros((0, 3)))
    )
    initial = dict(initial or {})

    # --- blocks, filters, groups --------------------------------------------------------
    keys = list(models)
    image_of: dict[str, tuple[Any, int]] = {}
    for key in keys:
        for slot, name in enumerate(_names(key)):
            if not isinstance(name, str) or not name:
                raise AdjustmentError(f"image names must be non-empty strings, got {name!r}")
            if name in image_of:
                raise AdjustmentError(f"image {name!r} is given twice")
            image_of[name] = (key, slot)
        if not isinstance(key, str) and not hasattr(models[key], "image"):
            raise AdjustmentError(
                f"{_label(key)}: a model for several images must have an image(i) method"
            )
    parts = {}
    for key in keys:
        spec = _per_key(filters, key)
        parts[key] = partition_block(models[key], spec, f"model {_label(key)}")
    clashes = shared_leaves([parts[k] for k in keys], [_label(k) for k in keys])
    if clashes:
        raise AdjustmentError(
            f"models {clashes[0]} share adjustable parameters (the same arrays): give them as one "
            "multi-image model under a tuple of image names, e.g. {('fore', 'aft'): sequence}"
        )
    by_sig: dict[Any, list] = {}
    for key in keys:
        sig = (isinstance(key, tuple), signature(*parts[key], len(_names(key))))
        by_sig.setdefault(sig, []).append(key)
    groups, labels, block_at = [], [], {}
    for (multi, _), members in by_sig.items():
        g = len(groups)
        groups.append(make_group([parts[k] for k in members], [_names(k) for k in members], multi))
        labels.append(tuple(members))
        for k, key in enumerate(members):
            block_at[key] = (g, k)
    image_index = {name: (*block_at[key], slot) for name, (key, slot) in image_of.items()}

    # --- observations ---------------------------------------------------------------------
    obs = observations
    xy = np.asarray(obs.xy, dtype=float)
    sig_px = np.asarray(obs.sigma_px, dtype=float)
    for i, (pid, img) in enumerate(zip(obs.point_ids, obs.images, strict=True)):
        if img not in image_index:
            raise AdjustmentError(
                f"observation {i} of point {pid!r} names unknown image {img!r} "
                f"(images: {_list(image_index)})"
            )
        if not (np.all(np.isfinite(xy[i])) and np.isfinite(sig_px[i]) and sig_px[i] > 0):
            raise AdjustmentError(
                f"observation {i} of point {pid!r} in image {img!r} has a non-finite coordinate "
                f"or a non-positive sigma: x, y = {xy[i].tolist()}, sigma = {sig_px[i]}"
            )
    lonlath = np.asarray(ground.lonlath, dtype=float)
    for i, pid in enumerate(ground.ids):
        if not np.all(np.isfinite(lonlath[i])):
            raise AdjustmentError(f"ground point {pid!r} has non-finite coordinates {lonlath[i]}")
        if np.any(~(np.asarray(ground.sigma_m[i]) > 0)):
            raise AdjustmentError(f"ground point {pid!r} has a non-positive or NaN sigma")
    gindex = {pid: i for i, pid in enumerate(ground.ids)}

    # --- points ---------------------------------------------------------------------------
    point_ids = list(dict.fromkeys(obs.point_ids))
    pindex = {pid: j for j, pid in enumerate(point_ids)}
    role = [ground.role[gindex[p]] if p in gindex else "tie" for p in point_ids]
    unmeasured = [p for p in ground.ids if p not in pindex]
    if unmeasured:
        warnings.warn(
            f"ground point(s) {_list(unmeasured)} are not measured in any image: ignored",
            stacklevel=3,
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
            f"point(s) {_list(lonely)} are seen in one image only and have no ground coordinates "
            f"(image {images_of_point[lonely[0]][0]!r}): they cannot be determined; measure "
            "them in a second image, give them as GCPs, or remove them"
        )

    # --- control per image ------------------------------------------------------------------
    if check_control:
        for name, (g, k, _slot) in image_index.items():
            key = labels[g][k]
            need = required_gcps(models[key], parts[key][0])
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
                    f"got {len(gcps)}" + (f" ({_list(gcps)})" if gcps else "")
                )
            if isinstance(models[key], Affine3D) and _coplanar(lonlath[[gindex[p] for p in gcps]]):
                raise TooFewControlPoints(
                    f"image {name!r}: the GCPs {_list(gcps)} are (near-)coplanar; the 3D affine "
                    "model needs at least 4 non-coplanar GCPs"
                )

    # --- initial ground points -------------------------------------------------------------
    origin = np.full((len(point_ids), 3), np.nan)
    for j, (pid, r) in enumerate(zip(point_ids, role, strict=True)):
        if pid in initial:
            origin[j] = np.asarray(initial[pid], dtype=float)
        elif r == "gcp":
            origin[j] = lonlath[gindex[pid]]
    image_models = {
        name: groups[g].image_model(groups[g].block_at(groups[g].theta0, k), slot)
        for name, (g, k, slot) in image_index.items()
    }
    todo = [j for j in range(len(point_ids)) if not np.all(np.isfinite(origin[j]))]
    _intersect_points(todo, point_ids, obs, xy, sig_px, image_models, origin)

    # --- arrays ---------------------------------------------------------------------------
    obs_img = np.array([image_index[img] for img in obs.images], dtype=np.int64).reshape(-1, 3)
    obs_pt = np.array([pindex[p] for p in obs.point_ids], dtype=np.int64)
    images, order = [], []
    for g in range(len(groups)):
        for slot in range(groups[g].n_slots):
            sel = np.flatnonzero((obs_img[:, 0] == g) & (obs_img[:, 2] == slot))
            if sel.size == 0:
                continue
            order.append(sel)
            images.append(
                ImageObs(
                    block=jnp.asarray(obs_img[sel, 1]),
                    point=jnp.asarray(obs_pt[sel]),
                    xy=jnp.asarray(xy[sel]),
                    weight=jnp.asarray(1.0 / sig_px[sel]),
                    group=g,
                    slot=slot,
                )
            )
    # every point with ground coordinates gets a ground observation, with weight 0 for check
    # points: the arrays, hence the compiled solve, do not depend on which points are GCPs
    known = [p for p, r in zip(point_ids, role, strict=True) if r in ("gcp", "check")]
    gsig = np.asarray([ground.sigma_m[gindex[p]] for p in known], dtype=float).reshape(-1, 3)
    is_gcp = np.array([ground.role[gindex[p]] == "gcp" for p in known], dtype=bool)
    gweight = np.where(np.isfinite(gsig) & is_gcp.reshape(-1, 1), 1.0 / gsig, 0.0)
    gobs = GroundObs(
        point=jnp.asarray(np.array([pindex[p] for p in known], dtype=np.int64)),
        lonlath=jnp.asarray(lonlath[[gindex[p] for p in known]].reshape(-1, 3)),
        weight=jnp.asarray(gweight.reshape(-1, 3)),
    )
    prior_mean, prior_weight, n_prior_rows = [], [], 0
    for g, grp in enumerate(groups):
        means = []
        for key in labels[g]:
            theta_k = np.asarray(grp.theta0)[labels[g].index(key)]

            def partition(tree, key=key):
                return partition_block(tree, _per_key(filters, key), f"prior of {_label(key)}")

            pr = _prior(_per_key(prior_sigma, key), (theta_k, grp.n_params), key, partition)
            means.append(pr)
        if any(m is not None for m in means):
            mean = np.stack([m[0] if m else np.zeros(grp.n_params) for m in means])
            weight = np.stack([m[1] if m else np.zeros(grp.n_params) for m in means])
            n_prior_rows += int(np.count_nonzero(weight))
        else:
            mean = weight = np.zeros((grp.n_blocks, 0))
        prior_mean.append(jnp.asarray(mean))
        prior_weight.append(jnp.asarray(weight))
        for key in labels[g]:
            n_prior_rows += int(np.prod(jax.eval_shape(block_priors, models[key]).shape))
    n_rows = 2 * len(obs.point_ids) + int(np.count_nonzero(np.asarray(gobs.weight))) + n_prior_rows
    groups_t, images_t = tuple(groups), tuple(images)
    problem = Problem(
        groups=groups_t,
        images=images_t,
        ground=gobs,
        origin=jnp.asarray(origin),
        metres_per_unit=jnp.asarray(metres_per_unit_np(origin)),
        prior_mean=tuple(prior_mean),
        prior_weight=tuple(prior_weight),
        structure=make_structure(groups_t, images_t, gobs, len(point_ids)),
        n_rows=n_rows,
        loss=loss,
        loss_scale=float(loss_scale),
    )
    param_names = tuple(
        f"{_label(label)}{name}"
        for g, grp in enumerate(groups)
        for label in labels[g]
        for name in grp.param_names
    )
    return Setup(
        problem=problem,
        labels=tuple(labels),
        image_index=image_index,
        point_ids=tuple(point_ids),
        point_role=tuple(role),
        obs_order=np.concatenate(order) if order else np.zeros(0, dtype=np.int64),
        ground_ids=tuple(known),
        param_names=param_names,
    )


def _intersect_points(todo, point_ids, obs, xy, sig_px, image_models, origin) -> None:
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
                f"point(s) {_list(bad)} could not be intersected from images {_list(imgs)} "
                "with the initial models (rays nearly parallel, or far outside the models' domain)"
            )
        for r, j in enumerate(members):
            if j in need:
                origin[j] = ground[r]
