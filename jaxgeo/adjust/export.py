"""Writing an adjustment: adjusted models (JSON and RPC files), points, residuals, report.

Nothing the user gave is overwritten: every path is checked against the inputs and against
existing files before anything is written, and each file is written atomically.
"""

from __future__ import annotations

import csv
import io
import json
import os
import pathlib
from collections.abc import Iterable
from typing import Any

import equinox as eqx
import jax
import numpy as np

from ..io.atomic import atomic_write_text
from ..io.rpc_common import vendor_values
from ..io.rpc_text import format_rpc_txt
from ..models import RPC, Biased
from ..models.bias import Shift
from .report import format_reports


def adjusted_rpc(model: Any) -> tuple[RPC, float, str]:
    """An RPC equivalent to an adjusted ``Biased(RPC, bias)``: ``(rpc, max_error_px, how)``.

    A shift folds exactly into the image offsets (``how = "exact"``). A bias with drift or
    affine terms mixes the sample and line rational functions, whose denominators differ, so
    the RPC is re-fitted to the biased model over its validity cube (``how = "refit"``,
    ``max_error_px`` the maximum error on the independent check grid).
    """
    if isinstance(model, RPC):
        return model, 0.0, "exact"
    if not (isinstance(model, Biased) and isinstance(model.model, RPC)):
        raise TypeError(f"no RPC form for a {type(model).__name__} model")
    rpc = model.model
    a0, m = (np.asarray(x) for x in _coefficients(model.bias))
    if isinstance(model.bias, Shift) or not np.any(m):
        folded = RPC(
            rpc.num,
            rpc.den,
            rpc.ground_offset,
            rpc.ground_scale,
            np.asarray(rpc.image_offset) - a0,
            rpc.image_scale,
        )
        return folded, 0.0, "exact"
    from ..models.rpc_fit import fit_rpc

    off, scale = np.asarray(rpc.image_offset), np.asarray(rpc.image_scale)
    n_cols, n_rows = (int(round(o + s)) + 1 for o, s in zip(off, scale, strict=True))
    go, gs = np.asarray(rpc.ground_offset), np.asarray(rpc.ground_scale)
    refit, report = fit_rpc(model, n_cols, n_rows, (go[2] - gs[2], go[2] + gs[2]))
    return refit, float(report.check_max_px), "refit"


@eqx.filter_jit
def _coefficients(bias):
    return bias.coefficients()


def _csv(header: list[str], rows: Iterable[Iterable[Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def _r(v: float) -> str:
    return repr(float(v))


def _leaves(tree) -> dict[str, Any]:
    out = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        out[jax.tree_util.keystr(path)] = np.asarray(leaf).tolist()
    return out


def models_json(result) -> dict[str, Any]:
    """JSON-ready adjusted models: per image the RPC (vendor names) and bias, or the parameters,
    with a posteriori sigmas of every adjusted parameter."""
    images = {}
    for name, model in result.models.items():
        entry: dict[str, Any] = {"model": type(model).__name__}
        key = next(k for k in result.blocks if k == name or (not isinstance(k, str) and name in k))
        own = result.parameters(key)
        entry["parameters"] = {k: v for k, (v, _) in own.items()}
        entry["sigmas"] = {k: s for k, (_, s) in own.items()}
        inner = model.model if isinstance(model, Biased) else model
        if isinstance(inner, RPC):
            entry["rpc"] = vendor_values(inner)
        if isinstance(model, Biased):
            entry["bias"] = {"kind": type(model.bias).__name__, **_leaves(model.bias)}
        images[name] = entry
    return {"images": images}


def write_outputs(
    out_dir: os.PathLike,
    result,
    report_text: str,
    report: dict[str, Any],
    inputs: Iterable[os.PathLike] = (),
    overwrite: bool = False,
    rpc_files: bool = True,
) -> list[pathlib.Path]:
    """Write the adjustment into ``out_dir``; refuse to touch an input or (unless
    ``overwrite``) an existing file. Returns the paths written."""
    out = pathlib.Path(out_dir)
    files: dict[str, str] = {}
    notes = []
    if rpc_files:
        for name, model in result.models.items():
            try:
                rpc, err, how = adjusted_rpc(model)
            except TypeError:
                continue
            files[f"{name}_adjusted_RPC.TXT"] = format_rpc_txt(rpc)
            notes.append(
                f"{name}_adjusted_RPC.TXT: {how}"
                + (f" (max error {err:.3g} px on the check grid)" if how == "refit" else "")
            )
    files["adjusted_models.json"] = json.dumps(models_json(result), indent=1) + "\n"
    files["ground_adjusted.csv"] = _csv(
        ["id", "lon", "lat", "h", "role", "sigma_e_m", "sigma_n_m", "sigma_h_m"],
        [
            [p, *(_r(v) for v in g), role, *(_r(v) for v in s)]
            for p, role, g, s in zip(
                result.point_ids,
                result.point_role,
                result.ground,
                result.ground_sigma_m,
                strict=True,
            )
        ],
    )
    files["residuals.csv"] = _csv(
        ["id", "image", "vx_px", "vy_px", "wx", "wy", "blunder"],
        [
            [p, img, _r(v[0]), _r(v[1]), _r(w[0]), _r(w[1]), int(b)]
            for p, img, v, w, b in zip(
                result.observation_ids,
                result.observation_images,
                result.residuals_px,
                result.standardized,
                result.blunders,
                strict=True,
            )
        ],
    )
    files["report.json"] = json.dumps(report, indent=1) + "\n"
    files["report.txt"] = report_text + ("\n\n" + "\n".join(notes) if notes else "") + "\n"
    targets = {n: (out / n).resolve() for n in files}
    given = {pathlib.Path(p).resolve() for p in inputs}
    for path in targets.values():
        if path in given:
            raise FileExistsError(f"{path}: refusing to write an adjusted file over an input")
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path}: exists (choose another --out or pass --overwrite)")
    return [atomic_write_text(targets[n], text, overwrite=overwrite) for n, text in files.items()]


__all__ = ["adjusted_rpc", "format_reports", "models_json", "write_outputs"]
