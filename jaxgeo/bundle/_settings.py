"""How a block is adjusted, besides the solver: :class:`AdjustSettings`.

:class:`jaxgeo.lsq.SolverConfig` says how the least squares run (method, loss, tolerances,
gross errors); :class:`AdjustSettings` what :func:`jaxgeo.adjust` and
:func:`jaxgeo.bundle.adjust_files` adjust and hold: the bias priors, the jitter spline, the tie
heights, the adjustable leaves, the starting points and the checks. Built once (e.g. from the
command line) and passed whole, so that the entry points and the stages share it instead of
copying a keyword list.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

from ..models import JitterBias
from ..models.internal import KNOT_SIGMA_PX


class JitterSettings(NamedTuple):
    """The spline of ``bias="jitter"`` (:class:`~jaxgeo.models.JitterBias`).

    ``knot_lines``: a knot every that many lines; ``None`` (default): chosen per image when the
    block is prepared, from its lines and its measurements (:mod:`._prepare.jitter`: about
    100 lines, which follows a jitter of a period of 400 lines or more to < 0.1 px,
    benchmarks/accuracy/jitter.py; wider where the measurements are sparse along the lines or
    the problem would grow too large). A spacing given is used as it is, and refused when it
    asks for more knots than the image's measurements support or than the memory bounds allow.
    ``smoothness_px``: prior sigma (px) of the coefficients' second differences;
    ``knot_sigma_px``: prior sigma (px) of each coefficient about zero (holds a knot no
    measurement reaches and what the images do not observe)."""

    knot_lines: float | None = None
    smoothness_px: float = 1.0
    knot_sigma_px: float = KNOT_SIGMA_PX

    def bias(self, lines: tuple[float, float]) -> JitterBias:
        """A zero :class:`~jaxgeo.models.JitterBias` over image lines ``lines = (first,
        last)``: with this spacing, or, without one, a one-segment placeholder whose spacing
        the preparation of the block chooses (``auto_knots``)."""
        first, last = (float(v) for v in lines)
        auto = self.knot_lines is None
        return JitterBias(
            (first, last),
            (last - first) if auto else self.knot_lines,
            self.smoothness_px,
            knot_sigma_px=self.knot_sigma_px,
            auto_knots=auto,
        )


DEFAULT_JITTER = JitterSettings()


@dataclasses.dataclass(frozen=True, eq=False)
class AdjustSettings:
    """What an adjustment adjusts and holds (see the module docstring); every field optional.

    Attributes:
        bias_prior_shift_px: prior sigma (px) of every image bias's shift, ``None``: none
            (:func:`~._adjustment.bias_prior_sigma`; used where ``prior_sigma`` is not given).
        bias_prior_matrix: prior sigma (px/px) of the drift or affine matrix terms.
        jitter: the spline of ``bias="jitter"`` (:class:`JitterSettings`).
        tie_height: heights ``f(lonlat (n, 2)) -> (n,)`` m, e.g. a DEM
            (:func:`jaxgeo.io.read_dem`): every tie point gets its height at its initial
            position as an observation of sigma ``tie_height_sigma_m`` (m); this fixes what the
            ties leave open against the tie heights (e.g. the along-track parallax of a pair).
        tie_height_sigma_m: sigma (m) of those heights (> 0).
        filters: ``eqx.partition`` filter spec of the adjustable leaves, one for all models or
            a mapping keyed like the models; default each model's ``adjustable_filter()``.
        initial: initial ground points ``{id: (lon, lat, h)}`` (else GCP coordinates, else
            intersection).
        check_control: also apply the per-image GCP-count rule before solving (the models'
            ``required_gcps``); off by default: what is determined is checked on the normal
            equations and what is left open raises
            :class:`~._errors.SingularNormalEquations` naming the parameters.
        throw: raise :class:`~._errors.SingularNormalEquations` when unknowns are not
            determined and warn :class:`~._errors.NotConvergedWarning` when the solve did not
            converge (default); ``False``: the result says it (errors as data).
        sources: the files and lines the tables were read from, named in messages
            (:class:`~._prepare.checks.Sources`; :func:`~._files.adjust_files` fills it).
        image_domains: image name -> ``(x_min, y_min, x_max, y_max)`` px of the image's raster
            (:meth:`jaxgeo.io.SensorImage.domain`): its measurements must lie inside it; an
            image without one is checked against its RPC's image domain.
        progress: called with a line of text at each stage (solving, each snooping round).
    """

    bias_prior_shift_px: float | None = None
    bias_prior_matrix: float | None = None
    jitter: JitterSettings = DEFAULT_JITTER
    tie_height: Callable[[Any], Any] | None = None
    tie_height_sigma_m: float = 10.0
    filters: Any = None
    initial: Mapping[str, Any] | None = None
    check_control: bool = False
    throw: bool = True
    sources: Any = None  # a _prepare.checks.Sources (its package imports this module)
    image_domains: Mapping[str, Any] | None = None
    progress: Callable[[str], None] | None = dataclasses.field(default=None, repr=False)

    def __post_init__(self):
        for name in ("bias_prior_shift_px", "bias_prior_matrix"):
            value = getattr(self, name)
            if value is not None and not (0 < value < math.inf):
                raise ValueError(f"{name} must be a positive number or None, got {value!r}")
        if not (0 < self.tie_height_sigma_m < math.inf):
            raise ValueError(
                f"tie_height_sigma_m must be a positive number, got {self.tie_height_sigma_m!r}"
            )
        knots, smooth, sigma = self.jitter
        if not (
            (knots is None or 0 < knots < math.inf)
            and 0 < smooth < math.inf
            and 0 < sigma < math.inf
        ):
            raise ValueError(f"jitter must hold positive numbers, got {tuple(self.jitter)}")

    def replace(self, **changes) -> AdjustSettings:
        """A copy with ``changes``."""
        return dataclasses.replace(self, **changes)


DEFAULT_SETTINGS = AdjustSettings()
