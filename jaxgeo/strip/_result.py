"""The adjusted strip: :class:`StripResult`, and the RPCs refitted to its final models."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from ..bundle import AdjustResult, Prepared
from ..models import RPC, RPCFitReport, fit_rpcs
from ._config import RefitConfig, StripConfig
from ._delivery import Strip
from ._distribution import DistributionCheck
from ._level1 import Level1Input
from ._level2 import Level2Data
from ._report import GrossErrors, StripReport
from ._solve import Evaluation, TwoLevelSolution
from ._universal import UniversalCorrection, UniversallyCorrected


@dataclasses.dataclass(frozen=True)
class StripResult:
    """The adjusted strip.

    ``models``: sub-scene name -> final model (level-1 biased RPC + universal correction);
    ``level1``: the level-1 bundle (:class:`~jaxgeo.bundle.AdjustResult`: biases with
    sigmas, s0, tie residuals); ``correction``: the universal correction; ``report``: per
    sub-scene absolute accuracy and continuity (:class:`~._report.StripReport`); ``solution``:
    the raw arrays of :func:`~._solve.two_level`; ``config``: the configuration it ran with;
    ``timings_s``: setup, and the first (compiling) call of both levels; ``gross_errors``: the
    observations flagged (and removed) at both levels and the broken seams
    (:class:`~._report.GrossErrors`).
    """

    strip: Strip
    models: dict[str, UniversallyCorrected]
    level1: AdjustResult
    correction: UniversalCorrection
    distribution: DistributionCheck
    report: StripReport
    config: StripConfig
    solution: TwoLevelSolution = dataclasses.field(repr=False)
    evaluation: Evaluation = dataclasses.field(repr=False)
    inputs: Level1Input = dataclasses.field(repr=False)
    data: Level2Data = dataclasses.field(repr=False)
    timings_s: dict = dataclasses.field(default_factory=dict)
    gross_errors: GrossErrors | None = None

    @property
    def setup(self) -> Prepared:
        return self.level1.setup

    def updated_rpcs(
        self, refit: RefitConfig | None = None, names: Sequence[str] | None = None
    ) -> dict[str, tuple[RPC, RPCFitReport]]:
        """RPCs refitted to the final sub-scene models (all, or ``names``) on ``refit``'s
        terrain-independent grid (default ``RefitConfig()``) over the image and height range
        (default the vendor RPC's),
        with fit reports."""
        refit = RefitConfig() if refit is None else refit
        out = {}
        scenes = {s.name: s for s in self.strip.scenes}
        for name in names if names is not None else self.strip.names:
            model = self.models[name]
            rpc = self.strip.rpcs[name]
            if refit.h_range is None:
                h0 = float(rpc.ground_offset[2]) - float(rpc.ground_scale[2])
                h1 = float(rpc.ground_offset[2]) + float(rpc.ground_scale[2])
            else:
                h0, h1 = refit.h_range
            sc = scenes[name]
            ((fit, rep),) = fit_rpcs([model], sc.n_cols, sc.n_rows, (h0, h1), grid=refit.grid)
            out[name] = (fit, rep)
        return out
