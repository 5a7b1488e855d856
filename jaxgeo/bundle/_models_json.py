"""``adjusted_models.json``: the adjusted models of an adjustment, in their input models' frames.

Per image the delivered RPC (the model a bias wraps) and the adjusted bias, moved back to the
frame of the model the image was given with (:func:`framed_models`; docs/conventions.md,
"Pixel frames of crops"), with the adjusted parameters, their sigmas and the biases' joint
covariance as the adjustment has them (in the rasters' pixels). ``jaxgeo.io.open_image`` (every
command's ``--model IMG=FILE``) reads it back; ``jaxgeo dsm --orientation`` reads its covariance.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import jax
import numpy as np

from ..io.internal import JITTER_STATICS, reframed, vendor_values
from ..models import RPC, Biased, JitterBias


def delivered_rpcs(
    result, origins: Mapping[str, tuple[float, float]] | None = None
) -> dict[str, RPC | None]:
    """Image name -> the exact RPC of the model the adjustment started from, without its bias
    (``None`` if it has none): the validity domain of a refit, and the delivered RPC in the
    JSON. With
    ``origins`` (image name -> the model pixel of the raster's first pixel), in the frame of the
    image's input model (:func:`framed_models`)."""
    setup = result.setup
    groups = setup.problem.groups
    start = setup.image_models(groups, tuple(g.theta0 for g in groups))
    origins = origins or {}
    out = {}
    for name, model in start.items():
        # the model a bias wraps (its correction is written apart): a jitter's too, and that of
        # a start model already adjusted (restarted from an adjusted_models.json)
        rpc = (model.model if isinstance(model, Biased) else model).exact_rpc()
        out[name] = None if rpc is None else reframed(rpc, origins.get(name, (0.0, 0.0)))
    return out


def framed_models(
    result, origins: Mapping[str, tuple[float, float]] | None = None
) -> dict[str, Any]:
    """Image name -> the adjusted model in the frame of the model the image was given with:
    the adjustment's model (in the raster's pixels) moved back by the image's origin (``origins``:
    image name -> the model pixel of the raster's first pixel, a crop's origin; none: unmoved),
    exactly (:func:`jaxgeo.io.internal.reframed`: an RPC's offsets, a bias's shift and a jitter's
    first line)."""
    origins = origins or {}
    return {n: reframed(m, origins.get(n, (0.0, 0.0))) for n, m in result.models.items()}


def _leaves(tree) -> dict[str, Any]:
    out = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        out[jax.tree_util.keystr(path)] = np.asarray(leaf).tolist()
    return out


PIXEL_FRAME_NOTE = (
    "rpc and bias: in the pixels of the model each image was given with (a crop's product); "
    "a crop's geotransform or --image-origin applies to them as to that model. parameters, "
    "sigmas, covariance: the adjustment's, in the pixels of the rasters adjusted"
)


def models_json(result, origins: Mapping[str, tuple[float, float]] | None = None) -> dict[str, Any]:
    """JSON-ready adjusted models: per image the delivered RPC (vendor names) and adjusted bias
    (``"kind"``, its arrays, a jitter's ``line0``, ``knot_lines``, ``smoothness_px``) in the
    frame of the image's input model (``origins``: :func:`framed_models`), the adjusted
    parameters with their a posteriori sigmas (the adjustment's, in the rasters' pixels); the
    biases' joint covariance (:func:`bias_covariance`) under ``"covariance"``. What
    ``jaxgeo.io.open_image(raster, model=FILE, name=IMAGE)`` (``--model IMG=FILE``) reads back."""
    images = {}
    delivered = delivered_rpcs(result, origins)
    for name, model in framed_models(result, origins).items():
        entry: dict[str, Any] = {"model": type(model).__name__}
        key = next(k for k in result.blocks if k == name or (not isinstance(k, str) and name in k))
        own = result.parameters(key)
        entry["parameters"] = {k: v for k, (v, _) in own.items()}
        entry["sigmas"] = {k: s for k, (_, s) in own.items()}
        if delivered[name] is not None:
            entry["rpc"] = vendor_values(delivered[name])
        if isinstance(model, Biased):  # the correction on its own, with its kind
            entry["bias"] = {"kind": type(model.bias).__name__, **_leaves(model.bias)}
            if isinstance(model.bias, JitterBias):  # its static numbers: not pytree leaves
                entry["bias"].update({k: float(getattr(model.bias, k)) for k in JITTER_STATICS})
        images[name] = entry
    out: dict[str, Any] = {"pixel_frame": PIXEL_FRAME_NOTE, "images": images}
    joint = bias_covariance(result)
    if joint is not None:
        out["covariance"] = joint
    return out


JOINT_LEAVES = (".bias.shift_px[", ".bias.matrix[", ".bias.drift[")
"""The bias parameters whose joint covariance :func:`models_json` writes (not a jitter's
knots: a spline of a long image has hundreds)."""


def bias_covariance(result) -> dict[str, Any] | None:
    """The joint a posteriori covariance of every image's bias shift and matrix/drift terms,
    correlations between images included (px^2, px^2/px, ...): ``{"parameters": [names],
    "matrix": [[...]]}`` with the names of ``result.param_names`` (``left.bias.shift_px[0]``);
    ``None`` without a bias. What ``jaxgeo dsm --orientation`` propagates to its heights."""
    names = [n for n in result.param_names if any(leaf in n for leaf in JOINT_LEAVES)]
    if not names:
        return None
    import scipy.sparse  # here: 90 ms of every start otherwise

    idx = [result.param_names.index(n) for n in names]
    cov = result.param_cov
    if scipy.sparse.issparse(cov):  # a banded problem: within the band only
        sub = cov[idx][:, idx].toarray()
    else:
        sub = np.asarray(cov)[np.ix_(idx, idx)]
    return {"parameters": names, "matrix": [[float(v) for v in row] for row in sub]}


__all__ = [
    "JOINT_LEAVES",
    "PIXEL_FRAME_NOTE",
    "bias_covariance",
    "delivered_rpcs",
    "framed_models",
    "models_json",
]
