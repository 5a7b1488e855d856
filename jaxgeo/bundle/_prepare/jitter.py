"""The jitter splines of a block: knots placed per image, bounds checked, priors stated.

A :class:`~jaxgeo.models.JitterBias` made without a spacing (``auto_knots``: what
``bias="jitter"`` gives unless :class:`~jaxgeo.bundle.JitterSettings` names one) gets its knots
here, per image, from the lines it spans and the image's measurements::

    knot_lines = max(FLOOR_KNOT_LINES,                     # the finest spacing chosen
                     covered * OBS_PER_SEGMENT / n_obs,    # enough measurements per segment
                     lines / (MAX_AUTO_KNOTS - 3),         # the knots per image, capped
                     the spacing that keeps the Jacobian within AUTO_JACOBIAN_BYTES)

then widened to a whole number of segments over the lines. ``covered`` is the span of the
image's measurements along the lines (1st to 99th percentile). So the knots scale with the
scene's lines (30 segments on 3000 lines, 60 on 6000) until the cap or the memory bound.

Every spline, placed here or given, is refused (:class:`~.._errors.AdjustmentError` naming
``--jitter-knot-lines``) when it asks for more knots than its image's measurements support
(:data:`MIN_OBS_PER_KNOT`), more than :data:`MAX_KNOTS`, or a Jacobian above
:data:`MAX_JACOBIAN_BYTES`: the solver holds each measurement's Jacobian with respect to all the
parameters of its image, ``JACOBIAN_BYTES_PER_ENTRY`` bytes per measurement and parameter.

The priors that hold what the measurements leave open (the coefficients' ``knot_sigma_px``, the
second differences' ``smoothness_px``, the pinned mean and trend) are stated in
:attr:`~jaxgeo.bundle.Prepared.notes`, which the report prints.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import equinox as eqx
import numpy as np

from ...io import Observations
from ...models import Biased, JitterBias
from ...models.internal import PIN_SIGMA_PX
from .._errors import AdjustmentError
from .checks import label, listing

FLOOR_KNOT_LINES = 100.0
"""The finest spacing chosen automatically (lines): a cubic B-spline follows a jitter of a
period of 400 lines or more to < 0.1 px with it (benchmarks/accuracy/jitter.py)."""
OBS_PER_SEGMENT = 20
"""Measurements per knot segment (on average over the lines they cover) below which the
automatic spacing widens."""
MAX_AUTO_KNOTS = 256
"""Knots per image chosen automatically at most (a 40 000-line scene: a knot every 157 lines)."""
JACOBIAN_BYTES_PER_ENTRY = 40
"""Bytes the solver holds per measurement and parameter of its image: the Jacobian (2 rows)
and its product with the point blocks (3 columns), float64."""
AUTO_JACOBIAN_BYTES = 2 * 2**30
"""The automatic spacing keeps ``measurements x parameters x JACOBIAN_BYTES_PER_ENTRY`` below
this."""
MAX_JACOBIAN_BYTES = 16 * 2**30
"""A spacing given is refused above this."""
MAX_KNOTS = 2000
"""Knots per image at most, given or chosen."""
MIN_OBS_PER_KNOT = 4
"""A spacing given is refused when the image has fewer measurements than this per knot."""
OPTION = "--jitter-knot-lines"


def _jitter(model: Any) -> JitterBias | None:
    return model.bias if isinstance(model, Biased) and isinstance(model.bias, JitterBias) else None


def auto_knot_lines(lines: float, obs_lines: np.ndarray, n_obs_block: int) -> float:
    """The automatic spacing (lines) of a spline over ``lines`` lines of an image whose
    measurements lie at lines ``obs_lines``, in a block of ``n_obs_block`` measurements
    (module docstring); a whole number of segments over the lines."""
    n = obs_lines.size
    covered = float(np.subtract(*np.percentile(obs_lines, [99, 1]))) if n else lines
    by_obs = max(covered, FLOOR_KNOT_LINES) * OBS_PER_SEGMENT / max(n, 1)
    by_count = lines / (MAX_AUTO_KNOTS - 3)
    params = AUTO_JACOBIAN_BYTES / (JACOBIAN_BYTES_PER_ENTRY * max(n_obs_block, 1))
    knots = max((params - 6) / 2, 4.0)  # 6 affine parameters, 2 per knot
    by_memory = lines / max(knots - 3, 1.0)
    spacing = max(FLOOR_KNOT_LINES, by_obs, by_count, by_memory)
    segments = max(1, math.floor(lines / spacing))
    return lines / segments


def place_knots(
    models: Mapping[Any, Any], observations: Observations
) -> tuple[dict[Any, Any], dict[Any, JitterBias], tuple[str, ...]]:
    """``(models, placed, notes)``: the models with every automatic jitter spline given its
    knots (``placed``: key -> the new bias, for the priors given for the placeholder), each
    spline's bounds checked, and the notes that state the splines and their priors."""
    jitters = {k: b for k, m in models.items() if (b := _jitter(m)) is not None}
    if not jitters:
        return dict(models), {}, ()
    images = np.asarray(observations.images)
    n_block = len(images)
    try:
        rows = np.asarray(observations.xy, dtype=float).reshape(n_block, 2)[:, 1]
    except (TypeError, ValueError):  # malformed: refused by the checks of the observations
        rows = np.full(n_block, np.nan)
    out, placed, lines_notes = dict(models), {}, []
    for key, bias in jitters.items():
        obs_lines = rows[images == key] if isinstance(key, str) else rows[:0]
        obs_lines = obs_lines[np.isfinite(obs_lines)]
        first, last = bias.line0, bias.last_line
        if bias.auto_knots:
            spacing = auto_knot_lines(last - first, obs_lines, n_block)
            bias = JitterBias(
                (first, last), spacing, bias.smoothness_px, bias.shift_px, bias.matrix,
                knot_sigma_px=bias.knot_sigma_px,
            )  # fmt: skip
            out[key] = eqx.tree_at(lambda m: m.bias, models[key], bias)
            placed[key] = bias
            how = (
                f"chosen from its {last - first:g} lines and {obs_lines.size} measurements; "
                f"{OPTION} sets it"
            )
        else:
            how = "as given"
        check_knots(label(key), bias, None if placed.get(key) else obs_lines.size, n_block)
        n = bias.knots_px.shape[0]
        lines_notes.append(
            f"image {label(key)!r}: jitter spline of {n} knots, one every "
            f"{bias.knot_lines:.4g} lines over lines {first:g}..{last:g} ({how})"
        )
    notes = tuple(lines_notes) + _prior_notes(jitters, placed)
    return out, placed, notes


def _prior_notes(jitters: Mapping[Any, JitterBias], placed: Mapping[Any, JitterBias]):
    by_priors: dict[tuple[float, float], list[str]] = {}
    for key, bias in jitters.items():
        bias = placed.get(key, bias)
        by_priors.setdefault((bias.knot_sigma_px, bias.smoothness_px), []).append(label(key))
    return tuple(
        f"jitter priors of {listing(names)}: each spline coefficient 0 +- {sigma:g} px "
        f"(--jitter-knot-sigma-px), second differences +- {smooth:g} px "
        f"(--jitter-smoothness-px), the spline's mean and trend along the lines 0 +- "
        f"{PIN_SIGMA_PX:g} px (the affine bias holds them); what the measurements leave open "
        "(a knot beyond them, the offsets common to the images or along the epipolar "
        "direction without GCPs or a DEM) stays at these priors"
        for (sigma, smooth), names in by_priors.items()
    )


def check_knots(name: str, bias: JitterBias, n_obs: int | None, n_obs_block: int) -> None:
    """Refuse a spline with more knots than ``n_obs`` measurements support (``None``: not
    checked, for a spacing chosen here), than :data:`MAX_KNOTS`, or whose Jacobian in a block
    of ``n_obs_block`` measurements would exceed :data:`MAX_JACOBIAN_BYTES` (messages name
    ``--jitter-knot-lines``)."""
    n = bias.knots_px.shape[0]
    lines = bias.last_line - bias.line0
    what = (
        f"image {name!r}: a jitter knot every {bias.knot_lines:g} lines ({OPTION}) gives "
        f"{n} knots over its {lines:g} lines"
    )
    support = n if n_obs is None else n_obs // MIN_OBS_PER_KNOT
    if n > support:
        need = lines / max(support - 3, 1)
        raise AdjustmentError(
            f"{what}, more than its {n_obs} measurements support (one knot per "
            f"{MIN_OBS_PER_KNOT} at most: {support}); give {OPTION} {math.ceil(need)} or more, "
            "or leave it out (chosen from the lines and the measurements)"
        )
    nbytes = JACOBIAN_BYTES_PER_ENTRY * n_obs_block * (6 + 2 * n)
    if n > MAX_KNOTS or nbytes > MAX_JACOBIAN_BYTES:
        per_obs = JACOBIAN_BYTES_PER_ENTRY * n_obs_block
        most = min(MAX_KNOTS, (MAX_JACOBIAN_BYTES / per_obs - 6) / 2)
        raise AdjustmentError(
            f"{what}: more than the solver can hold ({MAX_KNOTS} knots per image, and "
            f"{MAX_JACOBIAN_BYTES / 2**30:g} GiB of Jacobian for {n_obs_block} measurements "
            f"(this needs {nbytes / 2**30:.3g} GiB)); give {OPTION} "
            f"{math.ceil(lines / max(most - 3, 1))} or more"
        )


def regrid_sigma(sigma: Any, key: Any, bias: JitterBias) -> Any:
    """A prior sigma given for a placeholder spline's model (a pytree like it), its knots'
    sigma spread over ``bias``'s knots (one value for all: e.g. :func:`bias_prior_sigma`'s
    ``inf``); scalars and ``None`` as they are."""
    old = _jitter(sigma) if isinstance(sigma, Biased) else None
    if old is None:
        if isinstance(sigma, np.ndarray | list | tuple) and np.ndim(sigma) > 0:
            raise AdjustmentError(
                f"{label(key)}: a raveled prior sigma cannot follow the jitter knots chosen "
                f"here: give it as a pytree like the model, or give {OPTION}"
            )
        return sigma
    values = np.unique(np.asarray(old.knots_px, dtype=float))
    if values.size > 1:
        raise AdjustmentError(
            f"{label(key)}: prior sigmas of the jitter knots differ per knot, but the knots are "
            f"chosen here: give one value for all, or give {OPTION}"
        )
    knots = np.full(bias.knots_px.shape, values[0] if values.size else np.inf)
    leaves = (np.asarray(old.shift_px), np.asarray(old.matrix), knots)
    spread = eqx.tree_at(lambda b: (b.shift_px, b.matrix, b.knots_px), bias, leaves)
    return eqx.tree_at(lambda m: m.bias, sigma, spread)  # the new spline's static fields
