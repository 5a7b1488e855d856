"""``jaxgeo.adjust``: bundle block adjustment of any set of sensor models, in one call.

Input: sensor models keyed by image name, image observations with a priori sigmas (px), and
ground points (GCPs as weighted observations with a sigma per east/north/up axis; check points
adjusted as tie points, their coordinates only used in the report). Output: an
:class:`~._result.AdjustResult` with the adjusted models, s0, parameter covariances, residuals
per observation, ground points with sigmas, and the convergence status (a non-converged solve
warns with :class:`~._errors.NotConvergedWarning` and returns the last state).

The stages: :func:`~._prepare.prepare` (checks, groups, initial points, priors) ->
:func:`jaxgeo.lsq.solve` (Schur LM, covariance, singularity test; jitted) ->
:func:`~._result.make_result` (names, statistics, report).
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from collections.abc import Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import numpy as np

from ..io import (
    DEM,
    GroundPoints,
    Observations,
    read_ground,
    read_observations,
    read_rpc,
    table_lines,
)
from ..lsq import DEFAULT_SOLVER, SolverConfig
from ..models import BIAS_KINDS, AbstractBias, AbstractSensorModel, Biased
from ._export import write_outputs
from ._prepare import prepare
from ._prepare.checks import Sources
from ._report import AccuracyReport, direct_georeferencing, format_reports
from ._result import AdjustResult, make_result
from ._snooping import snoop

BIAS_CHOICES = ("none", *BIAS_KINDS)
"""Names accepted for ``bias``: ``"none"`` and the kinds of
:data:`jaxgeo.models.BIAS_KINDS` (defined there once)."""


def with_bias(models: Mapping[str, Any], bias: str | type[AbstractBias] | None) -> dict[str, Any]:
    """Wrap every single-image model in :class:`~jaxgeo.models.Biased` with a zero bias.

    ``bias``: a name of :data:`BIAS_CHOICES` (``"shift"``, ``"shift-drift"``, ``"affine"``), a
    bias class, or ``None``/``"none"`` (models unchanged). Models that are already
    :class:`Biased` (and multi-image models) are kept as they are.
    """
    if bias is None or bias == "none":
        return dict(models)
    kind = BIAS_KINDS.get(bias) if isinstance(bias, str) else bias
    if kind is None:
        raise ValueError(f"unknown bias {bias!r}; expected one of {', '.join(BIAS_CHOICES)}")
    return {
        k: m
        if isinstance(m, Biased) or not isinstance(m, AbstractSensorModel)
        else Biased(m, kind())
        for k, m in models.items()
    }


def bias_prior_sigma(
    models: Mapping[Any, Any], shift_px: float | None, matrix: float | None
) -> dict[Any, Any] | None:
    """Prior sigmas of the image biases as :func:`adjust` takes them (per model key): ``shift_px``
    (px) on every bias shift, ``matrix`` (px/px) on the other bias terms (drift or affine
    matrix); ``None`` for no prior. The names of ``jaxgeo strip``'s ``--bias-prior-*``."""
    if shift_px is None and matrix is None:
        return None
    out = {}
    for key, m in models.items():
        if not isinstance(m, Biased):
            continue
        sigma = jax.tree.map(lambda x: np.full(np.shape(x), np.inf), m)
        for name in m.bias.__dataclass_fields__:
            value = shift_px if name == "shift_px" else matrix
            leaf = getattr(m.bias, name)
            if value is None or not eqx.is_array(leaf):
                continue
            sigma = eqx.tree_at(
                lambda t, n=name: getattr(t.bias, n), sigma, np.full(np.shape(leaf), value)
            )
        out[key] = sigma
    return out


def adjust(
    models: Mapping[Any, Any],
    observations: Observations,
    ground: GroundPoints | None = None,
    *,
    bias: str | type[AbstractBias] | None = None,
    filters: Any = None,
    prior_sigma: Any = None,
    initial: Mapping[str, Any] | None = None,
    solver: SolverConfig = DEFAULT_SOLVER,
    check: bool = False,
    sources: Sources | None = None,
    tie_height: Any = None,
    tie_height_sigma_m: float = 10.0,
    throw: bool = True,
) -> AdjustResult:
    """Bundle block adjustment.

    Args:
        models: image name -> sensor model; a multi-image model (``image(i)`` views sharing
            parameters, e.g. a ``KeplerSequence``) under a tuple of image names.
        observations: image measurements (``jaxgeo.io.read_observations``).
        ground: GCPs and check points (``jaxgeo.io.read_ground``); points measured in images
            but absent here are tie points.
        bias: wrap every single model in ``Biased(model, bias())`` first (a name of
            :data:`BIAS_CHOICES` or a bias class); the bias leaves are then adjusted.
        filters: ``eqx.partition`` filter spec of the adjustable leaves, one for all models or a
            mapping keyed like ``models``; default each model's ``adjustable_filter()``.
        prior_sigma: optional parameter priors (``theta0 +- sigma``): scalar, raveled array or
            a pytree like the model, one for all or per model key (``inf`` = no prior).
        initial: optional initial ground points ``{id: (lon, lat, h)}`` (else intersection).
        solver: method, loss, tolerances, blunder threshold (:class:`jaxgeo.lsq.SolverConfig`).
        check: also apply the per-image GCP-count rule before solving (the models'
            ``required_gcps``: 1 shift, 2 shift+drift, 3 affine, 4 non-coplanar for the 3D
            affine model). Off by default: an image without GCPs of its own is adjusted when tie
            points connect it to controlled images; what is actually determined is checked on
            the normal equations (rank, null space), and what GCPs and ties leave open raises
            :class:`~._errors.SingularNormalEquations` naming the parameters (fix it with
            bias priors, ``prior_sigma``, see :func:`bias_prior_sigma`).

        sources: the files and lines the tables were read from, named in messages
            (:class:`~._prepare.checks.Sources`; :func:`adjust_files` fills it).
        tie_height: heights ``f(lonlat (n, 2)) -> (n,)`` m, e.g. a DEM
            (:func:`jaxgeo.io.read_dem`): every tie point gets its height at its initial
            position as an observation of sigma ``tie_height_sigma_m`` (m); this fixes what the
            ties leave open against the tie heights (e.g. an image's shift along the
            epipolar direction, the along-track parallax of a pair).
        throw: raise :class:`~jaxgeo.bundle.SingularNormalEquations` when unknowns are not
            determined and warn :class:`~jaxgeo.bundle.NotConvergedWarning` when the solve
            did not converge (default, as :func:`jaxgeo.lsq.solve`'s ``throw``); ``False``:
            return the result and let ``result.converged``, ``result.result`` and
            ``result.message`` say it (errors as data). Bad input is refused either way.

    Pre-flight checks (:mod:`~._prepare.checks`) refuse, naming the observation or point (and
    file and line with ``sources``): a point measured twice in one image, a ground id given
    twice, a measurement outside its image, a GCP or check point outside the validity cube of
    the RPC of an image it is measured in.

    Raises :class:`~._errors.AdjustmentError` (bad input, too few GCPs) before solving, and
    :class:`~._errors.SingularNormalEquations` naming the undetermined parameters or points.
    """
    if bias is not None:
        models = with_bias(models, bias)
    setup = prepare(
        models,
        observations,
        ground,
        filters=filters,
        prior_sigma=prior_sigma,
        initial=initial,
        check_control=check,
        sources=sources,
        tie_height=tie_height,
        tie_height_sigma_m=tie_height_sigma_m,
    )
    sol, rem_i, rem_g, rounds = snoop(setup, solver)
    return make_result(
        setup, sol, observations, ground, solver, (rem_i, rem_g), rounds, throw=throw
    )


@dataclasses.dataclass(frozen=True)
class FileAdjustment:
    """An adjustment of files (:func:`adjust_files`): the result, direct georeferencing with the
    given models (``None`` without ground points or with one image), and what was read."""

    result: AdjustResult
    direct: AccuracyReport | None
    bias: str
    inputs: tuple[pathlib.Path, ...]

    def summary(self) -> dict[str, Any]:
        """JSON-ready: s0, redundancy, convergence, check points, per image RMS and parameters
        with sigmas, blunders, and the direct-georeferencing report."""
        result, direct = self.result, self.direct
        rep = result.report.to_dict() if result.report is not None else None
        empty = {"n": 0, "rms_m": [None] * 3, "min_m": [None] * 3, "max_m": [None] * 3}
        images = {}
        for name in result.models:
            rms = rep["images"].get(name, {}).get("rms_px", [None, None]) if rep else [None] * 2
            own = result.parameters(name)
            images[name] = {
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
            "checkpoints": rep["checkpoints"] if rep else empty,
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
        }

    def format(self) -> str:
        """The text report: status, tables 3-4 of 000_ side by side, parameters, blunders."""
        result = self.result
        lines = [
            f"bundle adjustment ({self.bias} bias): {result.message} in {result.num_steps} "
            f"steps, s0 = {result.s0:.3f}, redundancy {result.redundancy}"
        ]
        reports = [r for r in (self.direct, result.report) if r is not None]
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
            lines.append(f"{what} ({len(flagged)} observations): {', '.join(flagged)}")
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
                f"check points excluded from the statistics (an observation flagged): "
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
        ``images``, ``rpc_format``, ``copy_images``, ``write_into`` of :func:`write_outputs`."""
        return write_outputs(
            out_dir, self.result, self.format(), self.summary(), self.inputs, overwrite=overwrite,
            **rpc_options,
        )  # fmt: skip


def adjust_files(
    images: Mapping[str, str | os.PathLike | str],
    observations: str | os.PathLike | str,
    ground: str | os.PathLike | str | None = None,
    *,
    bias: str = "affine",
    solver: SolverConfig = DEFAULT_SOLVER,
    bias_prior_shift_px: float | None = None,
    bias_prior_matrix: float | None = None,
    direct_roles: Sequence[str] = ("gcp", "check"),
    dem: Any = None,
    tie_height_sigma_m: float = 10.0,
) -> FileAdjustment:
    """Read the RPC files (image name -> path), OBS.csv and GROUND.csv, adjust with an image
    bias per image (a name of :data:`BIAS_CHOICES`; optional priors on it,
    :func:`bias_prior_sigma`; tie heights from ``dem``, a :class:`~jaxgeo.io.DEM`, with
    sigma ``tie_height_sigma_m``), and intersect the ``direct_roles`` points
    with the given RPCs for comparison (tables 3 and 4 of 000_)."""
    if bias not in BIAS_CHOICES:
        raise ValueError(f"unknown bias {bias!r}; expected one of {', '.join(BIAS_CHOICES)}")
    models = {name: read_rpc(path) for name, path in images.items()}
    obs = read_observations(observations)
    points = read_ground(ground) if ground is not None else None
    sources = Sources(
        str(observations),
        table_lines(observations),
        str(ground) if ground is not None else None,
        table_lines(ground) if ground is not None else (),
    )
    if bias != "none":
        models = with_bias(models, bias)
    prior = bias_prior_sigma(models, bias_prior_shift_px, bias_prior_matrix)
    result = adjust(
        models, obs, points, prior_sigma=prior, solver=solver, sources=sources, tie_height=dem,
        tie_height_sigma_m=tie_height_sigma_m,
    )  # fmt: skip
    direct = None
    if points is not None and len(models) >= 2:
        direct = direct_georeferencing(models, obs, points, roles=tuple(direct_roles))
    inputs = [*images.values(), observations] + ([ground] if ground is not None else [])
    inputs += [dem.path] if isinstance(dem, DEM) else []
    return FileAdjustment(result, direct, bias, tuple(pathlib.Path(p) for p in inputs))
