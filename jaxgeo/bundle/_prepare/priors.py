"""Parameter priors: the models' own soft constraints and the user's ``theta0 +- sigma``.

A prior is a weighted residual per parameter block: the model's ``prior_residuals()`` (orbit
and attitude constraints of the physical models, none for RPCs) and, when the user gives a
``prior_sigma``, ``(theta - theta0) / sigma`` on its adjustable parameters (``inf`` = none).
A jitter spline's coefficients get ``theta0 +- knot_sigma_px``
(:class:`~jaxgeo.models.JitterBias`) where the user gives none: as a parameter prior, so that
the solver's test of what is determined knows that a prior holds them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Float

from ..._runtime.arrays import device_array
from ...lsq import ModelGroup
from ...models import Biased, JitterBias
from .._errors import AdjustmentError
from .checks import label
from .grouping import partition_block, per_key, ravel_stacked


def prior_from_sigma(
    sigma: Any, theta0: np.ndarray, key: Any, partition: Callable[[Any], Any]
) -> tuple[np.ndarray, np.ndarray] | None:
    """Raveled ``(mean, weight)`` of a parameter prior (``sigma``: scalar, array or pytree
    like the model, ``partition``-ed like it); ``None`` without a prior."""
    if sigma is None:
        return None
    p = theta0.shape[0]
    if np.ndim(sigma) == 0 and not dataclasses.is_dataclass(sigma):
        sig = np.full(p, float(sigma))
    elif isinstance(sigma, np.ndarray | jax.Array | list | tuple) and np.size(sigma) == p:
        sig = np.asarray(sigma, dtype=float).reshape(p)
    else:
        dyn, _ = partition(sigma)
        sig = ravel_stacked([np.asarray(x)[None] for x in jax.tree.leaves(dyn)], 1)[0]
    if sig.shape != (p,) or np.any(~(sig > 0)):
        raise AdjustmentError(
            f"{label(key)}: prior sigma must be positive, one per adjustable parameter ({p})"
        )
    weight = np.where(np.isfinite(sig), 1.0 / sig, 0.0)
    return np.asarray(theta0, dtype=float), weight


def with_knot_prior(
    user: tuple[np.ndarray, np.ndarray] | None,
    model: Any,
    theta0: np.ndarray,
    key: Any,
    partition: Callable[[Any], Any],
) -> tuple[np.ndarray, np.ndarray] | None:
    """``user`` (a raveled ``(mean, weight)`` or ``None``) with ``theta0 +- knot_sigma_px`` on
    a jitter spline's coefficients where it has no weight."""
    if not (isinstance(model, Biased) and isinstance(model.bias, JitterBias)):
        return user
    sigma = jax.tree.map(lambda x: np.full(np.shape(x), np.inf), model)
    knots = np.full(np.shape(model.bias.knots_px), model.bias.knot_sigma_px)
    sigma = eqx.tree_at(lambda m: m.bias.knots_px, sigma, knots)
    _, weight = prior_from_sigma(sigma, theta0, key, partition)
    if user is None:
        return np.asarray(theta0, dtype=float), weight
    mean, given = user
    return mean, np.where(given > 0, given, weight)


def prior_arrays(
    groups: Sequence[ModelGroup],
    labels: Sequence[Sequence[Any]],
    models: Mapping[Any, Any],
    filters: Any,
    prior_sigma: Any,
) -> tuple[tuple[Float[Array, "b p"], ...], tuple[Float[Array, "b p"], ...], int]:
    """Per group ``(prior_mean, prior_weight)`` (``(n_blocks, 0)`` without user priors) and the
    number of prior rows (user priors with non-zero weight plus the models' own residuals)."""
    prior_mean, prior_weight, n_rows = [], [], 0
    for g, grp in enumerate(groups):
        means = []
        for k, key in enumerate(labels[g]):
            spec = per_key(filters, key)
            spec = models[key].adjustable_filter() if spec is None else spec

            def partition(tree, key=key, spec=spec):
                return partition_block(tree, spec, f"prior of {label(key)}")

            theta_k = np.asarray(grp.theta0)[k]
            user = prior_from_sigma(per_key(prior_sigma, key), theta_k, key, partition)
            means.append(with_knot_prior(user, models[key], theta_k, key, partition))
        if any(m is not None for m in means):
            mean = np.stack([m[0] if m else np.zeros(grp.n_params) for m in means])
            weight = np.stack([m[1] if m else np.zeros(grp.n_params) for m in means])
            n_rows += int(np.count_nonzero(weight))
        else:
            mean = weight = np.zeros((grp.n_blocks, 0))
        prior_mean.append(device_array(mean))
        prior_weight.append(device_array(weight))
        for key in labels[g]:
            n_rows += int(np.prod(jax.eval_shape(models[key].prior_residuals).shape))
    return tuple(prior_mean), tuple(prior_weight), n_rows
