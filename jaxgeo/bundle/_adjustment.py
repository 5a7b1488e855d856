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

from collections.abc import Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import numpy as np

from .._runtime.progress import Stages
from ..io import GroundPoints, Observations
from ..lsq import SolverConfig
from ..lsq.internal import DEFAULT_SOLVER
from ..models import AbstractBias, AbstractSensorModel, Biased
from ..models.internal import BIAS_KINDS
from ._diagnose import checked_geometry
from ._prepare import prepare
from ._result import AdjustResult, make_result
from ._settings import DEFAULT_JITTER, DEFAULT_SETTINGS, AdjustSettings, JitterSettings
from ._snooping import snoop

BIAS_CHOICES = ("none", *BIAS_KINDS, "jitter")
"""Names accepted for ``bias``: ``"none"``, the kinds of :data:`jaxgeo.models.BIAS_KINDS`
(defined there once) and ``"jitter"`` (:class:`~jaxgeo.models.JitterBias`: the affine bias
plus smooth offsets along the lines, :class:`JitterSettings`)."""


def image_lines(model: Any, domain: Sequence[float] | None = None) -> tuple[float, float]:
    """``(first, last)`` image line a model is used over: from ``domain`` (``(x_min, y_min,
    x_max, y_max)`` px, e.g. :meth:`jaxgeo.io.SensorImage.domain`), else its RPC's image
    domain. Raises ``ValueError`` when neither bounds it."""
    if domain is not None and np.all(np.isfinite(np.asarray(domain, float))):
        return float(domain[1]), float(domain[3])
    rpc = model.base_rpc() if isinstance(model, AbstractSensorModel) else None
    if rpc is None:
        raise ValueError(
            f"bias 'jitter' needs the lines of each image: a {type(model).__name__} model "
            "without an RPC and without its raster's size"
        )
    off, scale = float(rpc.image_offset[1]), abs(float(rpc.image_scale[1]))
    return off - scale, off + scale


def with_bias(
    models: Mapping[str, Any],
    bias: str | type[AbstractBias] | None,
    domains: Mapping[str, Sequence[float]] | None = None,
    jitter: JitterSettings = DEFAULT_JITTER,
) -> dict[str, Any]:
    """Wrap every single-image model in :class:`~jaxgeo.models.Biased` with a zero bias.

    ``bias``: a name of :data:`BIAS_CHOICES` (``"shift"``, ``"shift-drift"``, ``"affine"``,
    ``"jitter"``), a bias class, or ``None``/``"none"`` (models unchanged). Models that are
    already :class:`Biased` (and multi-image models) are kept as they are. A jitter's spline
    spans each image's lines (:func:`image_lines` of ``domains[name]``) with ``jitter``'s knots.
    """
    if bias is None or bias == "none":
        return dict(models)
    if bias == "jitter":
        domains = domains or {}

        def kind(name, m):
            return jitter.bias(image_lines(m, domains.get(name)))
    else:
        cls = BIAS_KINDS.get(bias) if isinstance(bias, str) else bias
        if cls is None:
            raise ValueError(f"unknown bias {bias!r}; expected one of {', '.join(BIAS_CHOICES)}")

        def kind(name, m):
            return cls()

    return {
        k: m
        if isinstance(m, Biased) or not isinstance(m, AbstractSensorModel)
        else Biased(m, kind(k, m))
        for k, m in models.items()
    }


def bias_prior_sigma(
    models: Mapping[Any, Any], shift_px: float | None, matrix: float | None
) -> dict[Any, Any] | None:
    """Prior sigmas of the image biases as :func:`adjust` takes them (per model key): ``shift_px``
    (px) on every bias shift, ``matrix`` (px/px) on the drift or affine matrix (a jitter's
    spline has its own smoothness prior); ``None`` for no prior. The names of ``jaxgeo
    strip``'s ``--bias-prior-*``."""
    if shift_px is None and matrix is None:
        return None
    out = {}
    for key, m in models.items():
        if not isinstance(m, Biased):
            continue
        sigma = jax.tree.map(lambda x: np.full(np.shape(x), np.inf), m)
        for name in m.bias.__dataclass_fields__:  # a jitter's knots: their own prior
            value = {"shift_px": shift_px, "matrix": matrix, "drift": matrix}.get(name)
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
    prior_sigma: Any = None,
    solver: SolverConfig = DEFAULT_SOLVER,
    settings: AdjustSettings = DEFAULT_SETTINGS,
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
            :data:`BIAS_CHOICES` or a bias class; a jitter's spline as ``settings.jitter``
            says); the bias leaves are then adjusted.
        prior_sigma: optional parameter priors (``theta0 +- sigma``): scalar, raveled array or
            a pytree like the model, one for all or per model key (``inf`` = no prior); default
            the bias priors of ``settings`` (:func:`bias_prior_sigma`), if any.
        solver: method, loss, tolerances, blunder threshold (:class:`jaxgeo.lsq.SolverConfig`).
        settings: the rest (:class:`~._settings.AdjustSettings`): bias priors, the jitter
            spline, tie heights (e.g. a DEM) and their sigma, the adjustable leaves
            (``filters``), initial points, the per-image GCP-count rule (``check_control``;
            off by default: an image without GCPs of its own is adjusted when tie points
            connect it to controlled images; what is actually determined is checked on the
            normal equations, and what GCPs and ties leave open raises
            :class:`~._errors.SingularNormalEquations` naming the parameters: fix it with bias
            priors), the files named in messages, the images' raster domains, a ``progress``
            callback.
        throw: raise :class:`~jaxgeo.bundle.SingularNormalEquations` when unknowns are not
            determined and warn :class:`~jaxgeo.bundle.NotConvergedWarning` when the solve
            did not converge (default, as :func:`jaxgeo.lsq.solve`'s ``throw``); ``False``:
            return the result and let ``result.converged``, ``result.result`` and
            ``result.message`` say it (errors as data). Bad input is refused either way.

    Pre-flight checks (:mod:`~._prepare.checks`) refuse, naming the observation or point (and
    file and line with ``settings.sources``): a point measured twice in one image, a ground id
    given twice, a measurement outside its image (its raster's size with
    ``settings.image_domains``, else its RPC's image domain), a GCP or check point outside the
    validity cube of the RPC of an image it is measured in, two images with the same RPC.

    Gross errors: a robust loss, then data snooping (:func:`~._snooping.snoop`), which removes
    at most ``max(1, 20 %)`` of the GCPs and of each image's observations: beyond that the
    models do not fit, and :class:`~._errors.PoorFitWarning` says so (``result.poor_fit``);
    the check-point statistics are reported with (``report_all``) and without (``report``)
    the check points that have a flagged observation.

    Raises :class:`~._errors.AdjustmentError` (bad input, too few GCPs) before solving, and
    :class:`~._errors.SingularNormalEquations` naming the undetermined parameters or points.
    """
    s = settings
    if bias is not None:
        models = with_bias(models, bias, s.image_domains, s.jitter)
    if prior_sigma is None:
        prior_sigma = bias_prior_sigma(models, s.bias_prior_shift_px, s.bias_prior_matrix)
    setup = prepare(
        models, observations, ground, prior_sigma=prior_sigma, settings=s,
        check_control=s.check_control,
    )  # fmt: skip
    stages = Stages(s.progress)  # each solve's line with the time the last one took
    sol, rem_i, rem_g, rounds = snoop(setup, solver, progress=stages)
    stages.done(f"solved ({rounds} snooping round{'s' * (rounds != 1)})")
    result = make_result(
        setup, sol, observations, ground, solver, (rem_i, rem_g), rounds, throw=throw
    )
    return checked_geometry(result, (rem_i, rem_g))  # a block without GCPs: its geometry
