"""What the adjusted strip gives back: the JSON summary, the text report, the refitted RPCs.

:func:`strip_output_paths` checks every destination before any work (inputs are never replaced,
existing files only with ``overwrite``); :func:`write_strip_outputs` writes one RPC per sub-scene
refitted to its final model (``NAME_RPC.TXT``, ``NAME.RPB``, OSSIM ``NAME.geom`` or DIMAP v2
``RPC_NAME.XML``), ``report.json`` and
``report.txt``, each atomically.
"""

from __future__ import annotations

import json
import math
import os
import pathlib
from collections.abc import Iterable
from typing import Literal

import numpy as np

from ..io import write_dimap_rpc, write_ossim_geom, write_rpb, write_rpc_text
from ..io.internal import atomic_write_text, sidecar_name
from ._config import RefitConfig
from ._delivery import Strip
from ._errors import ConfigError, Setting
from ._result import StripResult
from ._universal import TERM_NAMES

REFIT_WARN_PX = 0.01
"""A refitted RPC whose check-grid error exceeds this (px) deserves a warning."""

RPCFormat = Literal["txt", "rpb", "geom", "dimap"]
SUFFIX = {"txt": "_RPC.TXT", "rpb": ".RPB", "geom": ".geom", "dimap": ".XML (RPC_ prefix)"}
"""The updated RPC formats (file names: :func:`jaxgeo.io.sidecar_name`)."""
_WRITERS = {
    "txt": write_rpc_text,
    "rpb": write_rpb,
    "geom": write_ossim_geom,
    "dimap": lambda rpc, path, overwrite: write_dimap_rpc(rpc, path, overwrite=overwrite)[0],
}


def _finite(value):
    """JSON-safe copy: non-finite floats -> ``None``, numpy scalars/arrays -> Python."""
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def strip_summary(result: StripResult, rpc_fits: dict | None = None) -> dict:
    """The JSON object of ``jaxgeo strip --json`` (and ``report.json``): the settings, the GCP
    distribution check, the report (:meth:`~._report.StripReport.to_dict`), the universal
    correction, per sub-scene (``models``) the level-1 bias with a posteriori sigmas and, given
    ``rpc_fits`` (name -> :class:`~jaxgeo.models.RPCFitReport`), the refit error of its
    updated RPC (px); non-finite numbers become ``null``."""
    corr = result.correction
    dist = result.distribution
    names = result.strip.names
    models = {}
    for name in names:
        own = result.level1.parameters(name)
        models[name] = {
            "bias": {k: v for k, (v, _) in own.items()},
            "bias_sigma": {k: s for k, (_, s) in own.items()},
        }
        if rpc_fits is not None and name in rpc_fits:
            rep = rpc_fits[name]
            models[name]["rpc_refit_px"] = {
                "fit_rms": rep.fit_rms_px,
                "check_rms": rep.check_rms_px,
                "check_max": rep.check_max_px,
                "h_range_m": list(rep.h_range_m),
            }
    coeffs = np.asarray(corr.coeffs)
    files = result.strip.files
    data = {
        "strip": str(files.description) if files is not None else None,
        "options": result.config.to_dict(),
        "distribution": {
            "ok": dist.ok,
            "gcp_scenes": [names[k] for k in dist.gcp_scenes],
            "gaps": [[names[lo], names[hi]] for lo, hi in dist.gaps],
            "missing_head": dist.missing_head,
            "missing_tail": dist.missing_tail,
            "message": dist.message(names),
        },
        "report": result.report.to_dict(),
        "correction": {
            "degree": result.config.level2.degree,
            "terms": list(TERM_NAMES),
            "normalisation": "lat_n = (lat - offset[0]) / scale[0], lon_n = (lon - offset[1]) "
            "/ scale[1]; dlat, dlon in degrees",
            "dlat_deg": coeffs[0].tolist(),
            "dlon_deg": coeffs[1].tolist(),
            "offset_latlon_deg": np.asarray(corr.offset).tolist(),
            "scale_latlon_deg": np.asarray(corr.scale).tolist(),
        },
        "models": models,
        "timings_s": dict(result.timings_s),
    }
    return _finite(data)


def format_strip_result(result: StripResult) -> str:
    """The plain-text report: the settings in one line, the tables, the correction, times."""
    c = result.config
    lines = [
        f"full-strip adjustment: {len(result.strip.names)} sub-scenes, level 1 {c.level1.bias} "
        f"bias per sub-scene ({'ties + GCPs' if c.level1.use_gcps else 'ties only'}, "
        f"{c.ties.per_pair} ties per pair), level 2 {c.level2.degree} universal correction",
        "",
        result.report.format(),
        "",
        f"universal correction (degrees; terms {', '.join(TERM_NAMES)} of normalised lat, lon):",
    ]
    for label, row in zip(("dlat", "dlon"), np.asarray(result.correction.coeffs), strict=True):
        lines.append(f"  {label} " + " ".join(f"{v: .3e}" for v in row))
    t = result.timings_s
    setup, solve = t.get("setup", 0.0), t.get("first_call", 0.0)
    lines.append(f"time: setup {setup:.1f} s, both levels {solve:.1f} s (including compilation)")
    return "\n".join(lines)


def strip_output_paths(
    strip: Strip,
    out: str | os.PathLike,
    rpc_format: RPCFormat = "txt",
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> dict[str, pathlib.Path]:
    """Output file name -> path in ``out``, checked before any work: refuses the strip's input
    files (and ``inputs``) and, without ``overwrite``, existing files."""
    out = pathlib.Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{{0}} {out}: exists and is not a directory", Setting("out"))
    if rpc_format not in SUFFIX:
        raise ConfigError(f"{{0}} must be one of {tuple(SUFFIX)}, got {rpc_format!r}",
                          Setting("rpc_format"))  # fmt: skip
    files = [sidecar_name(n, rpc_format) for n in strip.names] + ["report.json", "report.txt"]
    targets = {f: (out / f).resolve() for f in files}
    given = [*(strip.files.all() if strip.files is not None else ()), *inputs]
    given = {pathlib.Path(p).resolve() for p in given}
    for path in targets.values():
        if path in given:
            raise ValueError(f"{path}: refusing to write an output over an input")
    existing = [str(p) for p in targets.values() if p.exists()]
    if existing and not overwrite:
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        where = f"{existing[0]}{more}".replace("{", "{{").replace("}", "}}")
        raise ConfigError(
            f"{where}: exists; refusing to overwrite (choose another {{0}} or pass {{1}})",
            Setting("out"),
            Setting("overwrite", True),
        )
    return targets


def write_strip_outputs(
    result: StripResult,
    targets: dict[str, pathlib.Path],
    refit: RefitConfig | None = None,
    rpc_format: RPCFormat = "txt",
    overwrite: bool = False,
) -> dict:
    """Refit every sub-scene's RPC to its final model and write it, ``report.json`` and
    ``report.txt`` to ``targets`` (:func:`strip_output_paths`). Returns the
    :func:`strip_summary` with the refit errors and ``written`` (the paths, in writing order)."""
    updated = result.updated_rpcs(RefitConfig() if refit is None else refit)
    fits = {name: rep for name, (_, rep) in updated.items()}
    data = strip_summary(result, fits)
    refit_lines = "\n".join(
        f"{sidecar_name(n, rpc_format)}: RPC refitted to the final model, RMS "
        f"{r.check_rms_px:.2g} px, max {r.check_max_px:.2g} px on the check grid"
        for n, r in fits.items()
    )
    write = _WRITERS[rpc_format]
    written = [
        write(rpc, targets[sidecar_name(name, rpc_format)], overwrite=overwrite)
        for name, (rpc, _) in updated.items()
    ]
    data["written"] = [str(p) for p in [*written, targets["report.json"], targets["report.txt"]]]
    text = format_strip_result(result)
    atomic_write_text(targets["report.json"], json.dumps(data, indent=1) + "\n",
                      overwrite=overwrite)  # fmt: skip
    atomic_write_text(targets["report.txt"], f"{text}\n\n{refit_lines}\n", overwrite=overwrite)
    return data


def worst_refit(data: dict) -> tuple[str, float]:
    """The sub-scene whose refitted RPC differs most from its final model, and by how much
    (px, on the check grid), from a :func:`write_strip_outputs` summary."""
    errors = {n: m["rpc_refit_px"]["check_max"] for n, m in data["models"].items()}
    worst = max(errors, key=lambda n: errors[n])
    return worst, errors[worst]
