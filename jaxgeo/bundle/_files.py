"""Adjusting files: images, OBS/GROUND tables and a DEM in, a :class:`FileAdjustment` out.

An image is a raster (its RPC in its tags or an ``.RPB``/``_RPC.TXT`` sidecar, or a separate
model file) or a model file alone (:func:`jaxgeo.io.open_image`). With a raster, its measurements
are checked against its size and its model works in its pixel frame (a crop's pixel-space
geotransform, or an origin given, folded in); with a model file alone, against the RPC's image
domain. Measurements refer to the pixels of the raster given; the adjusted models written
(:meth:`FileAdjustment.write`) are in the frame of the model each image was given with (the
full product for a crop with its product's model: the crop's origin is moved back out, so that
every reader applies it once; docs/conventions.md, "Pixel frames of crops"), except an RPC
beside a copy of the raster or in its tags (the raster's own pixels). A model given already
adjusted (an ``adjusted_models.json`` entry) starts the new bias from its values
(:func:`restarted`).

Without any GCP the block is a relative orientation: unless bias priors are given, the biases
get :data:`RELATIVE_PRIOR_SHIFT_PX` and :data:`RELATIVE_PRIOR_MATRIX` (a note says so), which
hold what the ties leave open (the block's position, the along-track parallax) near the given
models.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .._runtime.kept import beside_solve
from ..io import DEM, SensorImage, open_image, read_ground, read_observations
from ..io.internal import as_path, detect_rpc_format, is_remote, table_lines
from ..lsq import SolverConfig
from ..lsq.internal import DEFAULT_SOLVER
from ..models import AffineBias, Biased, JitterBias, ShiftBias, ShiftDriftBias
from ._adjustment import BIAS_CHOICES, adjust, bias_prior_sigma, with_bias
from ._export import RPCOutputs, write_outputs
from ._prepare.checks import Sources
from ._report import AccuracyReport, direct_georeferencing, format_reports
from ._result import AdjustResult
from ._settings import DEFAULT_SETTINGS, AdjustSettings

KNOWN_BIASES = (ShiftBias, ShiftDriftBias, AffineBias, JitterBias)
"""The biases a start model may carry (:func:`restarted`)."""
RELATIVE_PRIOR_SHIFT_PX = 10.0
"""Prior sigma (px) of the bias shifts when no GCP is given and no prior either: the given
models' pointing (a few px for current sensors) holds the block's position."""
RELATIVE_PRIOR_MATRIX = 1e-4
"""Prior sigma (px/px) of the bias drift or affine terms in the same case."""
LISTED = 50
"""Flagged observations named in the summary (all of them are in residuals.csv)."""


def image_inputs(image: SensorImage) -> tuple[os.PathLike, ...]:
    """The files ``image`` was (or may have been) read from: its raster, its model file, and
    the RPC sidecars GDAL reads beside the raster (``<stem>.RPB``, ``<stem>_RPC.TXT``)."""
    found = list(image.inputs)
    if image.path is not None:
        stem = image.path.with_suffix("")
        for suffix in (".RPB", ".rpb", "_RPC.TXT", "_rpc.txt"):
            side = stem.parent / (stem.name + suffix)
            if side.is_file():
                found.append(side)
    return tuple(dict.fromkeys(found))


def sensor_image(
    name: str,
    source: str | os.PathLike | SensorImage,
    model: str | os.PathLike | None = None,
    origin: tuple[float, float] | None = None,
) -> SensorImage:
    """The :class:`~jaxgeo.io.SensorImage` of ``source``: itself, a raster (with its own model,
    or ``model``, a model file, and ``origin``, a crop's model pixel of its first pixel), or a
    model file alone (any format :func:`jaxgeo.io.read_rpc` reads; ``origin`` applies to it,
    ``model`` does not). Raises ``FileNotFoundError`` naming the image and file."""
    if isinstance(source, SensorImage):
        return source
    path = as_path(source)  # a URL stays one (GDAL reads it; its absence: the server's error)
    if not is_remote(path) and not path.is_file():
        what = "is not a file" if path.exists() else "no such file"
        raise FileNotFoundError(f"image {name!r}: {path}: {what}")
    if detect_rpc_format(path) == "raster":
        return open_image(path, model=model, origin=origin, name=name)
    if model is not None:
        raise ValueError(
            f"image {name!r} is given as a model file ({path}) and with a model {model}: a "
            "separate model file applies to a raster; give the image's raster, or no model"
        )
    return open_image(model=path, origin=origin, name=name)


@dataclasses.dataclass(frozen=True)
class FileAdjustment:
    """An adjustment of files (:func:`adjust_files`): the result, direct georeferencing with the
    given models (``None`` without ground points or with one image), what was read (``inputs``,
    ``images``: name -> :class:`~jaxgeo.io.SensorImage`) and ``notes`` on what was assumed
    (e.g. the priors of a relative orientation)."""

    result: AdjustResult
    direct: AccuracyReport | None
    bias: str
    inputs: tuple[pathlib.Path, ...]
    images: Mapping[str, SensorImage] = dataclasses.field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def rpc_sources(self) -> dict[str, pathlib.Path]:
        """Image name -> the file its adjusted RPC is named and placed after: the raster when
        one was given, else the model file."""
        return {name: img.path or img.model_path for name, img in self.images.items()}

    def summary(self) -> dict[str, Any]:
        """JSON-ready: s0, redundancy, convergence, check points, per image RMS and parameters
        with sigmas, blunders, and the direct-georeferencing report."""
        result, direct = self.result, self.direct
        rep = result.report.to_dict() if result.report is not None else None
        rep_all = result.report_all.to_dict() if result.report_all is not None else None
        empty = {"n": 0, "rms_m": [None] * 3, "min_m": [None] * 3, "max_m": [None] * 3}
        images = {}
        for name in result.models:
            rms = rep["images"].get(name, {}).get("rms_px", [None, None]) if rep else [None] * 2
            own = result.parameters(name)
            img = self.images.get(name)
            images[name] = {
                "file": str(img.path or img.model_path) if img is not None else None,
                "size_px": list(img.size) if img is not None and img.size else None,
                "origin_px": list(img.origin) if img is not None else [0.0, 0.0],
                "rms_px": rms,
                "params": {k: v for k, (v, _) in own.items()},
                "sigmas": {k: s for k, (_, s) in own.items()},
            }
        blunders = [
            {"id": p, "image": img, "w": [float(x) for x in w]}
            for p, img, w, b in zip(
                result.observation_ids,
                result.observation_images,
                result.standardized,
                result.blunders,
                strict=True,
            )
            if b
        ]
        return {
            "bias": self.bias,
            "s0": result.s0 if result.s0 == result.s0 else None,
            "redundancy": result.redundancy,
            "converged": result.converged,
            "message": result.message,
            "num_steps": result.num_steps,
            "poor_fit": result.poor_fit or None,
            "checkpoints": rep["checkpoints"] if rep else empty,
            "checkpoints_all": rep_all["checkpoints"] if rep_all else empty,
            "images": images,
            "blunders": blunders,
            "removed": int(result.removed.sum()) if result.removed is not None else 0,
            "gcp_flagged": [
                {"id": p, "w": w, "removed": p in result.gcp_removed}
                for p, w in zip(result.gcp_flagged, result.gcp_w, strict=True)
            ],
            "checks_excluded": list(result.checks_excluded),
            "snooping_rounds": result.snooping_rounds,
            "direct": direct.to_dict() if direct is not None else None,
            "notes": list(self.notes),
        }

    def format(self) -> str:
        """The text report: status, tables 3-4 of 000_ side by side, parameters, blunders."""
        result = self.result
        lines = [
            f"bundle adjustment ({self.bias} bias): {result.message} in {result.num_steps} "
            f"steps, s0 = {result.s0:.3f}, redundancy {result.redundancy}"
        ]
        if not result.converged:
            lines.append("NOT CONVERGED: the figures below are those of the last state")
        lines += [f"note: {n}" for n in self.notes]
        if result.poor_fit:
            lines.append("POOR FIT: the observations do not fit the models (see the warning)")
        reports = [r for r in (self.direct, result.report) if r is not None]
        if result.report_all is not None and result.report_all is not result.report:
            reports.append(result.report_all)  # the flagged check points too
        if reports:
            lines += ["", format_reports(reports)]
        lines += ["", "adjusted parameters (a posteriori sigma):"]
        for name, value, sigma in zip(
            result.param_names, result.params, result.param_sigma, strict=True
        ):
            lines.append(f"  {name:<32} {value: .6g} +- {sigma:.2g}")
        flagged = [
            f"{p}@{img}"
            for p, img, b in zip(
                result.observation_ids, result.observation_images, result.blunders, strict=True
            )
            if b
        ]
        if flagged:
            gone = result.removed if result.removed is not None else np.zeros(len(flagged))
            what = "gross errors removed" if np.any(gone) else "possible gross errors (|w| > k)"
            more = len(flagged) - LISTED
            listed = ", ".join(flagged[:LISTED]) + (
                f", ... ({more} more: the 'blunder' column of residuals.csv)" if more > 0 else ""
            )
            lines.append(f"{what} ({len(flagged)} observations): {listed}")
        for p, w in zip(result.gcp_flagged, result.gcp_w, strict=True):
            j = result.gcp_ids.index(p)
            off = np.linalg.norm(np.nan_to_num(result.ground_residuals_m[j]))
            how = "removed (adjusted as a tie point)" if p in result.gcp_removed else "flagged"
            lines.append(
                f"GCP {p!r}: ground coordinates {off:.1f} m from the adjusted point "
                f"(w = {w:.1f}): {how}"
            )
        if result.checks_excluded:
            lines.append(
                f"check points with a flagged observation (in 'adjusted, all checks' only): "
                f"{len(result.checks_excluded)} ({', '.join(result.checks_excluded[:20])}"
                + (" ..." if len(result.checks_excluded) > 20 else "")
                + ")"
            )
        return "\n".join(lines)

    def write(
        self, out_dir: str | os.PathLike, overwrite: bool = False, **rpc_options
    ) -> list[pathlib.Path]:
        """Write the adjusted models, points, residuals and report (never over an input, nor
        over an existing file unless ``overwrite``); returns the paths written. ``rpc_options``:
        ``rpc_format``, ``copy_images``, ``write_into`` of :class:`~._export.RPCOutputs`
        (``images`` defaults to :meth:`rpc_sources`, ``origins`` to the images' origins). The
        models written as files of their own (``adjusted_models.json``, the RPC files, the
        jitter grids) are in the frame of each image's input model (a crop's product); an RPC
        beside a copy of the raster or in its tags, in the raster's pixels (GDAL's rule)."""
        if self.images:
            rpc_options.setdefault("images", self.rpc_sources())
            rpc_options.setdefault("origins", {n: im.origin for n, im in self.images.items()})
        return write_outputs(
            out_dir, self.result, self.format(), self.summary(), self.inputs, overwrite=overwrite,
            rpcs=RPCOutputs(**rpc_options),
        )  # fmt: skip


def restarted(
    models: Mapping[str, Any], bias: str, domains: Mapping[str, Sequence[float]], jitter
) -> dict[str, Any]:
    """:func:`~._adjustment.with_bias` of ``models``, where a model that already has a bias (an
    adjusted model, e.g. the ``adjusted_models.json`` entry of a previous adjustment) starts the
    new ``bias`` from its values instead of zero (the priors then hold the block near it): the
    wrapped model gets the new kind, initialised with the old shift and matrix (a jitter's
    spline least-squares fitted to the new knots). ``ValueError`` naming the image when the new
    kind cannot hold the old correction (e.g. ``shift`` after ``affine``, or a jitter dropped)."""
    plain = {
        n: m.model if isinstance(m, Biased) and isinstance(m.bias, KNOWN_BIASES) else m
        for n, m in models.items()
    }
    out = with_bias(plain, bias, domains, jitter)
    for name, model in models.items():
        if plain[name] is not model and isinstance(out[name], Biased):
            out[name] = Biased(plain[name], _started(out[name].bias, model.bias, name, bias))
    return out


def _started(new, old, name: str, kind: str):
    """The zero bias ``new`` with the values of ``old`` (:func:`restarted`)."""
    a0, m = (np.asarray(v, dtype=float) for v in old.coefficients())
    knots = None
    if isinstance(old, JitterBias):
        if not isinstance(new, JitterBias):
            raise ValueError(
                f"image {name!r}: its model holds a jitter correction; adjusting it with "
                f"--bias {kind} would drop it: use --bias jitter"
            )
        knots = _refitted_knots(old, new)
    if isinstance(new, ShiftBias) and np.any(m):
        raise ValueError(f"image {name!r}: its model's {type(old).__name__} has terms --bias "
                         f"{kind} cannot hold: use --bias affine")  # fmt: skip
    if isinstance(new, ShiftBias):
        return ShiftBias(a0)
    if isinstance(new, ShiftDriftBias):
        if np.any(m[:, 0]):
            raise ValueError(f"image {name!r}: its model's {type(old).__name__} has terms "
                             f"--bias {kind} cannot hold: use --bias affine")  # fmt: skip
        return ShiftDriftBias(a0, m[:, 1])
    if isinstance(new, AffineBias):
        return AffineBias(a0, m)
    n = new.knots_px.shape[0]
    lines = (new.line0, new.line0 + (n - 3) * new.knot_lines)
    return JitterBias(lines, new.knot_lines, new.smoothness_px, a0, m,
                      np.zeros((n, 2)) if knots is None else knots)  # fmt: skip


def _refitted_knots(old: JitterBias, new: JitterBias) -> np.ndarray:
    """The knots of ``new``'s layout whose spline is closest (least squares, 8 samples per knot
    spacing over ``new``'s lines) to ``old``'s: exact when the layouts agree."""
    n = new.knots_px.shape[0]
    if old.knots_px.shape[0] == n and (old.line0, old.knot_lines) == (new.line0, new.knot_lines):
        return np.asarray(old.knots_px)
    lines = np.linspace(new.line0, new.line0 + (n - 3) * new.knot_lines, 8 * (n - 3) + 1)
    basis = np.stack([np.asarray(JitterBias((new.line0, lines[-1]), new.knot_lines,
                                            knots_px=np.eye(n)[:, [j, j]]).offsets(lines))[:, 0]
                      for j in range(n)], axis=1)  # fmt: skip
    target = np.asarray(old.offsets(lines))
    return np.linalg.lstsq(basis, target, rcond=None)[0]


def adjust_files(
    images: Mapping[str, str | os.PathLike | SensorImage],
    observations: str | os.PathLike,
    ground: str | os.PathLike | None = None,
    *,
    bias: str = "affine",
    solver: SolverConfig = DEFAULT_SOLVER,
    settings: AdjustSettings = DEFAULT_SETTINGS,
    direct_roles: Sequence[str] = ("gcp", "check"),
) -> FileAdjustment:
    """Read the images (name -> raster, model file or :class:`~jaxgeo.io.SensorImage`, see the
    module docstring), OBS.csv and GROUND.csv, adjust with an image bias per image (a name of
    :data:`BIAS_CHOICES`) as ``solver`` and ``settings`` say (:class:`AdjustSettings`: bias
    priors, :func:`bias_prior_sigma`; tie heights from ``settings.tie_height``, e.g. a
    :class:`~jaxgeo.io.DEM`, with sigma ``tie_height_sigma_m``; the spline of
    ``bias="jitter"`` over each image's lines; a ``progress`` callback; the files and domains
    are filled in here), and intersect the ``direct_roles`` points with the given models for
    comparison (tables 3 and 4 of 000_)."""
    if bias not in BIAS_CHOICES:
        raise ValueError(f"unknown bias {bias!r}; expected one of {', '.join(BIAS_CHOICES)}")
    progress = settings.progress
    opened = {name: sensor_image(name, source) for name, source in images.items()}
    models = {name: img.model for name, img in opened.items()}
    domains = {name: img.domain() for name, img in opened.items() if img.size is not None}
    obs = read_observations(observations)
    points = read_ground(ground) if ground is not None else None
    sources = Sources(
        str(observations),
        table_lines(observations),
        str(ground) if ground is not None else None,
        table_lines(ground) if ground is not None else (),
    )
    if bias != "none":
        models = restarted(
            models, bias, {n: img.domain() for n, img in opened.items()}, settings.jitter
        )
    notes = []
    measured = set(obs.point_ids)
    gcps = [] if points is None else [
        p for p, r in zip(points.ids, points.role, strict=True) if r == "gcp" and p in measured
    ]  # fmt: skip
    del measured  # 4 MB for 100 000 ties, not to be held through the solve
    unheld = settings.bias_prior_shift_px is None and settings.bias_prior_matrix is None
    if not gcps and bias != "none" and unheld:
        shift, matrix = RELATIVE_PRIOR_SHIFT_PX, RELATIVE_PRIOR_MATRIX
        settings = settings.replace(bias_prior_shift_px=shift, bias_prior_matrix=matrix)
        notes.append(
            f"no GCP: a relative orientation; the image biases are held near the given models "
            f"by priors of {shift:g} px (shift) and {matrix:g} px/px "
            "(other terms) (--bias-prior-shift-px, --bias-prior-matrix), so the block keeps "
            "the given models' absolute position"
        )
    for name, img in opened.items():
        if img.path is not None and img.origin != (0.0, 0.0):
            notes.append(
                f"image {name!r} is a crop at model pixel {img.origin[0]:g}, {img.origin[1]:g} "
                "of its product: its measurements are in the crop's pixels; its adjusted models "
                "written (RPC, adjusted_models.json, jitter grid) in its input model's (the "
                "product's: the crop's geotransform or --image-origin applies to them as to "
                "the input model)"
            )
    prior = bias_prior_sigma(models, settings.bias_prior_shift_px, settings.bias_prior_matrix)
    settings = settings.replace(sources=sources, image_domains=domains)
    # direct georeferencing (the given models, for the report) beside the adjustment, from the
    # moment the runtime has traced the solve (`jaxgeo demo` cold: see the closing notes of
    # issue 29); an error of the adjustment comes first and it then does not run
    work = None
    if points is not None and len(models) >= 2:
        if progress is not None:
            progress("direct georeferencing: intersecting the control points with the given "
                     "models (beside the adjustment)")  # fmt: skip
        work = direct_georeferencing
    with beside_solve(work, models, obs, points, roles=tuple(direct_roles)) as direct:
        result = adjust(models, obs, points, prior_sigma=prior, solver=solver, settings=settings)
    direct = direct.result()
    notes += result.setup.notes  # what the preparation chose (a jitter's knots and priors)
    inputs = [p for img in opened.values() for p in image_inputs(img)]
    inputs += [observations] + ([ground] if ground is not None else [])
    dem = settings.tie_height
    inputs += [dem.path] if isinstance(dem, DEM) else []
    return FileAdjustment(
        result, direct, bias, tuple(pathlib.Path(p) for p in inputs), opened, tuple(notes)
    )
