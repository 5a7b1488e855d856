"""Configuration of the full-strip adjustment: small frozen modules instead of keyword lists.

``StripConfig(ties=TieConfig(...), level1=Level1Config(...), level2=Level2Config(...),
solver=SolverConfig(...))``; every field has the default of 003_ (affine bias per sub-scene,
50 formed ties per adjacent pair, quadratic universal correction) and is checked when the
config is made (a :class:`~._errors.ConfigError` naming the setting). Configs are host-side
settings; only the ``solver`` enters the compiled two-level call.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable
from typing import Any, Literal

import equinox as eqx
import numpy as np

from ..lsq import SolverConfig
from ..models.internal import BIAS_KINDS
from ._errors import ConfigError, Setting
from ._universal import N_TERMS

DEGREES = (*N_TERMS, "auto")
"""Universal-correction degrees: the leading terms of 003_ eq. 12-13 (:data:`._universal.N_TERMS`)
or ``"auto"``, the one that best predicts each GCP scene left out."""

TieHeight = float | Callable[[np.ndarray], np.ndarray] | None
"""A DEM ``f(lonlat (n, 2)) -> h (n,)`` (ellipsoidal m), a constant height (m), or ``None``."""


def _positive(value, path: str, *, allow_none: bool = False) -> None:
    if value is None and allow_none:
        return
    if not (isinstance(value, numbers.Real) and value > 0 and math.isfinite(value)):
        raise ConfigError(f"{{0}} must be a positive number, got {value}", Setting(path))


def _finite(value, path: str) -> None:
    if not (isinstance(value, numbers.Real) and math.isfinite(value)):
        raise ConfigError(f"{{0}} must be finite, got {value}", Setting(path))


class TieConfig(eqx.Module):
    """The formed tie points of level 1 (003_ section 8).

    Fields:
        per_pair: ties formed in the overlap of every adjacent pair of sub-scenes (>= 1).
        layout: ``"grid"`` (a regular grid spanning the overlap, default) or ``"random"``
            (uniform positions drawn with ``seed``).
        seed: the random layout's seed.
        margin_px: ties kept this far inside each overlap (px, >= 0): vendor RPC validity
            cubes end at the image edge.
        sigma_px: a priori sigma of a formed tie (px): the pixel is exact, this is the model
            error.
        height: where the tie heights come from (:data:`TieHeight`: a DEM callable, one height
            in m, or ``None``: the mean surveyed height of the strip's ground points).
        height_sigma_m: sigma of the tie height priors (m; smaller with a good DEM).
    """

    per_pair: int = eqx.field(static=True, default=50)
    layout: Literal["grid", "random"] = eqx.field(static=True, default="grid")
    seed: int = eqx.field(static=True, default=0)
    margin_px: float = eqx.field(static=True, default=100.0)
    sigma_px: float = eqx.field(static=True, default=0.1)
    height: TieHeight = None
    height_sigma_m: float = eqx.field(static=True, default=500.0)

    def __check_init__(self):
        if isinstance(self.per_pair, bool) or not isinstance(self.per_pair, numbers.Integral):
            raise ConfigError(f"{{0}} must be an integer, got {self.per_pair!r}",
                              Setting("ties.per_pair"))  # fmt: skip
        if self.per_pair < 1:
            raise ConfigError(f"{{0}} must be >= 1, got {self.per_pair}", Setting("ties.per_pair"))
        if self.layout not in ("grid", "random"):
            raise ConfigError(f"{{0}} must be 'grid' or 'random', got {self.layout!r}",
                              Setting("ties.layout"))  # fmt: skip
        _finite(self.margin_px, "ties.margin_px")
        if self.margin_px < 0:
            raise ConfigError(
                f"{{0}} must be >= 0, got {self.margin_px}", Setting("ties.margin_px")
            )
        _positive(self.sigma_px, "ties.sigma_px")
        if self.height is not None and not callable(self.height):
            _finite(self.height, "ties.height")
        _positive(self.height_sigma_m, "ties.height_sigma_m")


class Level1Config(eqx.Module):
    """Level 1: the bundle adjustment of all sub-scenes at once (003_ sections 6 and 8).

    Fields:
        bias: the image bias adjusted per sub-scene, a name of
            :data:`jaxgeo.models.BIAS_KINDS` (``"affine"`` as in 003_).
        use_gcps: level 1 sees the ties and the GCPs (default); ``False``: the ties only (the
            paper's pure flow, relative; the GCPs enter at level 2), which needs bias priors.
        bias_prior_shift_px: prior sigma (px) of every sub-scene's bias shift, or ``None``.
        bias_prior_matrix: prior sigma (px/px) of the affine matrix (or shift-drift drift)
            terms, or ``None``.
        bias_prior_sigma: any prior as :func:`jaxgeo.adjust` takes it (scalar, raveled array
            or a pytree like the biased model; ``inf`` = none); instead of the two above.
    """

    bias: str = eqx.field(static=True, default="affine")
    use_gcps: bool = eqx.field(static=True, default=True)
    bias_prior_shift_px: float | None = eqx.field(static=True, default=None)
    bias_prior_matrix: float | None = eqx.field(static=True, default=None)
    bias_prior_sigma: Any = None

    def __check_init__(self):
        if self.bias not in BIAS_KINDS:
            raise ConfigError(
                f"{{0}} must be one of {tuple(BIAS_KINDS)}, got {self.bias!r}",
                Setting("level1.bias"),
            )
        _positive(self.bias_prior_shift_px, "level1.bias_prior_shift_px", allow_none=True)
        _positive(self.bias_prior_matrix, "level1.bias_prior_matrix", allow_none=True)
        if self.bias_prior_matrix is not None and not self._matrix_field():
            raise ConfigError(f"{{0}}: the {self.bias} bias has no matrix terms",
                              Setting("level1.bias_prior_matrix"))  # fmt: skip
        if self.bias_prior_sigma is not None and self.has_simple_priors:
            raise ConfigError(
                "give {0} or {1} and {2}, not both",
                Setting("level1.bias_prior_sigma"),
                Setting("level1.bias_prior_shift_px"),
                Setting("level1.bias_prior_matrix"),
            )

    @property
    def has_simple_priors(self) -> bool:
        return self.bias_prior_shift_px is not None or self.bias_prior_matrix is not None

    @property
    def has_priors(self) -> bool:
        return self.bias_prior_sigma is not None or self.has_simple_priors

    def _matrix_field(self) -> str | None:
        """The bias leaf beside ``shift_px`` (``matrix``, ``drift``), or ``None``."""
        leaves = [f.name for f in dataclasses.fields(BIAS_KINDS[self.bias]) if f.name != "shift_px"]
        return leaves[0] if leaves else None

    def check_priors(self) -> None:
        """Level 1 on ties only fixes the biases' differences, not their common part: raise a
        :class:`~._errors.ConfigError` naming the priors it lacks."""
        if self.use_gcps or self.bias_prior_sigma is not None:
            return
        need = [] if self.bias_prior_shift_px is not None else ["level1.bias_prior_shift_px"]
        if self._matrix_field() and self.bias_prior_matrix is None:
            need.append("level1.bias_prior_matrix")
        if need:
            names = " and ".join(f"{{{k + 1}}}" for k in range(len(need)))
            raise ConfigError(
                f"level 1 with ties only ({{0}}) needs bias priors ({names}): ties fix the "
                "differences of the sub-scene biases, not their common part",
                Setting("level1.use_gcps", False),
                *(Setting(p) for p in need),
            )

    def prior_sigma(self, proto) -> Any:
        """The bias prior sigmas as :func:`jaxgeo.adjust` takes them, for the biased model
        ``proto`` (a pytree like it; ``None``: no prior)."""
        if not self.has_simple_priors:
            return self.bias_prior_sigma
        import jax

        sigma = jax.tree.map(lambda x: np.full(np.shape(x), np.inf), proto)
        if self.bias_prior_shift_px is not None:
            sigma = eqx.tree_at(
                lambda m: m.bias.shift_px, sigma, np.full(2, self.bias_prior_shift_px)
            )
        field = self._matrix_field()
        if self.bias_prior_matrix is not None and field is not None:
            sigma = eqx.tree_at(
                lambda m: getattr(m.bias, field),
                sigma,
                np.full(np.shape(getattr(proto.bias, field)), self.bias_prior_matrix),
            )
        return sigma


class Level2Config(eqx.Module):
    """Level 2: the universal lat/lon correction of 003_ eq. 12-13.

    ``degree``: one of :data:`DEGREES` (default ``"quadratic"``, the paper's).
    """

    degree: str = eqx.field(static=True, default="quadratic")

    def __check_init__(self):
        if self.degree not in DEGREES:
            raise ConfigError(f"{{0}} must be one of {DEGREES}, got {self.degree!r}",
                              Setting("level2.degree"))  # fmt: skip


class RefitConfig(eqx.Module):
    """The RPCs refitted to the final sub-scene models (:meth:`~._result.StripResult.updated_rpcs`).

    ``grid``: columns, rows and height layers of the terrain-independent fit grid (>= 4 each,
    for the cubic terms); ``h_range``: ``(min, max)`` height (m), default each vendor RPC's.
    """

    grid: tuple[int, int, int] = eqx.field(static=True, default=(21, 21, 7))
    h_range: tuple[float, float] | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if len(self.grid) != 3 or min(self.grid) < 4:
            raise ConfigError(f"{{0}} needs at least 4 points per axis, got {list(self.grid)}",
                              Setting("refit.grid"))  # fmt: skip
        if self.h_range is not None and not (
            len(self.h_range) == 2 and all(map(math.isfinite, self.h_range))
            and self.h_range[0] < self.h_range[1]
        ):  # fmt: skip
            raise ConfigError(f"{{0}} must be increasing and finite, got {self.h_range}",
                              Setting("refit.h_range"))  # fmt: skip


STRIP_SOLVER = SolverConfig(method="lm", loss="cauchy", max_steps=100, tol=1e-6)
"""The solver of the strip, :func:`jaxgeo.adjust`'s defaults: Cauchy loss at 3 a priori sigmas
(IRLS) on the image measurements and GCP coordinates, then data snooping (Baarda's w-test,
iterated) removing the flagged observations and re-solving (``remove_blunders=False``: flag
only), at level 1 and, with the same settings, at level 2 (:mod:`._snooping`). ``loss="l2"`` and
``remove_blunders=False`` give the plain least squares of the paper."""


class StripConfig(eqx.Module):
    """Everything :func:`~._adjustment.adjust_strip` needs besides the strip: the ties, the two
    levels, the solver (``jaxgeo.lsq.SolverConfig``: level 1's solve, and the robust
    loss and gross-error settings of both levels; default :data:`STRIP_SOLVER`), and whether a
    :class:`~._distribution.GCPDistributionWarning` is emitted when the GCP scenes break the
    rule of 003_ section 9."""

    ties: TieConfig = TieConfig()
    level1: Level1Config = Level1Config()
    level2: Level2Config = Level2Config()
    solver: SolverConfig = STRIP_SOLVER
    check_distribution: bool = eqx.field(static=True, default=True)

    def to_dict(self) -> dict[str, Any]:
        """The settings of a report (``jaxgeo strip --json``), one flat level of plain values."""
        t, s = self.ties, self.solver
        return dict(
            ties_per_pair=t.per_pair, tie_layout=t.layout, tie_margin_px=t.margin_px,
            tie_sigma_px=t.sigma_px, tie_height_sigma_m=t.height_sigma_m,
            bias=self.level1.bias, level1_gcps=self.level1.use_gcps, degree=self.level2.degree,
            method=s.method, loss=s.loss, loss_scale=s.loss_scale, max_steps=s.max_steps,
            tol=s.tol, blunder_k=s.blunder_k, remove_blunders=s.remove_blunders,
        )  # fmt: skip
