"""The adjusted models of ``jaxgeo adjust`` / ``jaxgeo strip``: ``adjusted_models.json`` read back.

The file holds, per image (``"images": {NAME: entry}``), the delivered RPC under ``"rpc"`` (the
vendor key names of :func:`~jaxgeo.io.internal.vendor_values`) and the adjusted correction under
``"bias"`` (``"kind"``: ``ShiftBias``, ``ShiftDriftBias``, ``AffineBias`` or ``JitterBias``, its
arrays under their pytree paths ``.shift_px``, ``.drift``, ``.matrix``, ``.knots_px`` and a
jitter's ``line0``, ``knot_lines``, ``smoothness_px``). Both are in the pixel frame of the model
the adjustment was given (the full product for a crop with a product's model: docs/conventions.md,
"Pixel frames of crops"), so the file is a model file like any other: a crop's geotransform (or
``--image-origin``) is applied to it when the image is opened. :func:`read_adjusted_model`
returns ``Biased(RPC, bias)``: the bias and the jitter applied wherever the model projects.
"""

from __future__ import annotations

import os

import numpy as np

from ..models import (
    RPC,
    AbstractSensorModel,
    AffineBias,
    Biased,
    JitterBias,
    ShiftBias,
    ShiftDriftBias,
)
from ._remote import as_path
from ._rpc_common import RPCFormatError, assemble_rpc, source_name
from ._rpc_json import parse_json
from ._rpc_keys import COEFFS, N_TERMS, SCALARS

JITTER_STATICS = ("line0", "knot_lines", "smoothness_px")
"""A :class:`~jaxgeo.models.JitterBias`'s fixed numbers, written beside its arrays."""
_ARRAYS = {
    "ShiftBias": (".shift_px",),
    "ShiftDriftBias": (".shift_px", ".drift"),
    "AffineBias": (".shift_px", ".matrix"),
    "JitterBias": (".shift_px", ".matrix", ".knots_px"),
}


def is_adjusted_models(root: object) -> bool:
    """Whether a parsed JSON object is an ``adjusted_models.json`` (an ``"images"`` object of
    entries that each hold a ``"model"`` name)."""
    images = root.get("images") if isinstance(root, dict) else None
    return (
        isinstance(images, dict)
        and bool(images)
        and all(isinstance(e, dict) and "model" in e for e in images.values())
    )


def adjusted_entry(path: str | os.PathLike, name: str | None = None) -> tuple[str, dict]:
    """``(image name, entry)`` of image ``name`` in the ``adjusted_models.json`` at ``path``;
    a file of one image gives its entry whatever the name. An unknown name, or no name, for a
    file of several images is an :class:`RPCFormatError` naming the file and the images it
    holds."""
    path = as_path(path)
    source = source_name(path)
    root = parse_json(path.read_text(encoding="utf-8"), source)
    if not is_adjusted_models(root):
        raise RPCFormatError(f'{source}: not an adjusted_models.json (no "images" entries)')
    images = root["images"]
    names = ", ".join(sorted(images))
    if len(images) == 1:
        name = next(iter(images))
    if name is None:
        raise RPCFormatError(
            f"{source}: holds the adjusted models of several images ({names}): name the "
            "image (--model IMG=FILE with IMG its file stem; open_image(..., name=))"
        )
    if name not in images:
        raise RPCFormatError(f"{source}: no image named {name!r}; it holds {names}")
    return name, images[name]


def read_adjusted_model(path: str | os.PathLike, name: str | None = None) -> AbstractSensorModel:
    """The adjusted model of image ``name`` (:func:`adjusted_entry`) in the
    ``adjusted_models.json`` at ``path``: its delivered RPC wrapped in its adjusted bias
    (``Biased(RPC, bias)``; an RPC for an entry without a bias or with a pure shift, folded
    exactly into its offsets), in the frame of the model the adjustment was given.
    :class:`RPCFormatError` naming the file, the image and the key at fault."""
    name, entry = adjusted_entry(path, name)
    where = f"{source_name(as_path(path))}: image {name!r}"
    if "rpc" not in entry:
        raise RPCFormatError(
            f"{where}: its {entry.get('model')} model has no RPC in the file (only its adjusted "
            "parameters): it cannot be read back as a model"
        )
    rpc = _rpc(entry["rpc"], where)
    if "bias" not in entry:
        return rpc
    model = Biased(rpc, _bias(entry["bias"], where))
    # a pure shift folds into the RPC's offsets exactly: the RPC's compiled kernel then serves
    # every projection (an ortho of the Ventoux crop: 7 s instead of 37 s on 2 cores)
    exact = model.exact_rpc()
    return model if exact is None else exact


def _rpc(values: object, where: str) -> RPC:
    """The RPC of an entry: :func:`~jaxgeo.io.internal.vendor_values`' names read back."""
    if not isinstance(values, dict):
        raise RPCFormatError(f'{where}: "rpc" must be an object of RPC values')
    scalars, coeffs = {}, {}
    for key in SCALARS:
        scalars[key] = _number(values, key, where, "rpc")
    for key in COEFFS:
        coeffs[key] = _array(values, key, where, (N_TERMS,), "rpc")
    return assemble_rpc(scalars, coeffs, where)


def _bias(values: object, where: str):
    if not isinstance(values, dict) or values.get("kind") not in _ARRAYS:
        kind = values.get("kind") if isinstance(values, dict) else values
        raise RPCFormatError(f"{where}: bias kind {kind!r} unknown (expected {', '.join(_ARRAYS)})")
    kind = values["kind"]
    shapes = {".knots_px": None, ".matrix": (2, 2)}
    arrays = [_array(values, key, where, shapes.get(key, (2,))) for key in _ARRAYS[kind]]
    if kind == "ShiftBias":
        return ShiftBias(*arrays)
    if kind == "ShiftDriftBias":
        return ShiftDriftBias(*arrays)
    if kind == "AffineBias":
        return AffineBias(*arrays)
    line0, knot_lines, smoothness = (_number(values, key, where) for key in JITTER_STATICS)
    shift, matrix, knots = arrays
    n = knots.shape[0]
    if knots.ndim != 2 or knots.shape[1] != 2 or n < 4 or not knot_lines > 0:
        raise RPCFormatError(
            f"{where}: bias.knots_px must be (n >= 4, 2) with knot_lines > 0, got "
            f"{knots.shape} and {knot_lines}"
        )
    return JitterBias((line0, line0 + (n - 3) * knot_lines), knot_lines, smoothness, shift,
                      matrix, knots)  # fmt: skip


def _array(
    values: dict, key: str, where: str, shape: tuple[int, ...] | None, group: str = "bias"
) -> np.ndarray:
    label = f"{group}.{key.lstrip('.')}"
    if key not in values:
        raise RPCFormatError(f"{where}: no {label}")
    try:
        out = np.asarray(values[key], dtype=float)
    except (TypeError, ValueError):
        raise RPCFormatError(f"{where}: {label} is not an array of numbers") from None
    if (shape is not None and out.shape != shape) or not np.all(np.isfinite(out)):
        raise RPCFormatError(
            f"{where}: {label} must be finite numbers of shape {shape or '(n, 2)'}, got "
            f"shape {out.shape}"
        )
    return out


def _number(values: dict, key: str, where: str, group: str = "bias") -> float:
    value = values.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise RPCFormatError(f"{where}: {group}.{key} must be a finite number, got {value!r}")
    return float(value)


__all__ = ["JITTER_STATICS", "adjusted_entry", "is_adjusted_models", "read_adjusted_model"]
