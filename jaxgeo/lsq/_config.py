"""Solver configuration: a small frozen module instead of a list of keywords.

``SolverConfig`` holds settings only (no arrays): every field is static, so a config is hashed
into the compiled solve and may be passed to ``jax.jit`` / ``eqx.filter_jit`` as it is.
"""

from __future__ import annotations

import math
import numbers
from typing import Literal

import equinox as eqx

METHODS = ("lm", "gn", "dense")
"""``"lm"`` Levenberg-Marquardt (Schur), ``"gn"`` Gauss-Newton (Schur), ``"dense"`` optimistix'
Levenberg-Marquardt with a dense QR (small problems and cross-checks only)."""
LOSSES = ("l2", "huber", "cauchy")
"""Losses on the image observations: least squares, Huber, Cauchy."""
BLUNDER_K = 3.29
"""Default threshold of the standardised residuals (Baarda's w-test at alpha = 0.001)."""

Method = Literal["lm", "gn", "dense"]
Loss = Literal["l2", "huber", "cauchy"]


class SolverConfig(eqx.Module):
    """How a bundle adjustment is solved.

    Fields:
        method: ``"lm"`` (Levenberg-Marquardt over the Schur complement, default), ``"gn"``
            (Gauss-Newton, same descent) or ``"dense"`` (optimistix LM, dense QR).
        loss: ``"l2"``, ``"huber"`` or ``"cauchy"`` (default) on the image observations and
            the GCP coordinates, solved by iteratively reweighted least squares
            (:func:`jaxgeo.lsq.solve`). Cauchy, as ASP's bundle_adjust: its influence
            falls off as ``c^2 / r`` beyond the threshold, so that a 100 px gross error pulls no
            harder than a 3 sigma residual (Huber's influence stays at ``c``: 10 % gross errors
            still bias a Huber solution), while residuals within ``c`` keep ~90 % of their weight
            (on clean data the solution is that of least squares within a fraction of sigma).
        loss_scale: the robust loss' threshold ``c`` in a priori sigmas (> 0; default 3: a
            clean observation is rarely beyond it).
        irls_iterations: reweighted solves at most after the least-squares start (>= 1).
        irls_tol: stop reweighting when no weight changes by more than this (> 0; default
            0.05). The reweighting only brings the solve near the M-estimate: the last phase,
            on the robust objective itself, converges to it (to ``tol``) whatever this is.
        tol: stop when the remaining Gauss-Newton step is below ``tol`` of its standard
            deviation (``"dense"``: optimistix' rtol = atol = ``tol``); >= 0.
        max_steps: solver steps at most, in all (>= 1; a robust loss' least-squares start and
            reweighting count too).
        blunder_k: flag observations whose standardised residual exceeds this (> 0).
        remove_blunders: data snooping (:mod:`jaxgeo.bundle._snooping`): remove the flagged
            observations (the worst first) and re-solve until none is flagged (default); with
            False they are flagged only.
        snooping_rounds: re-solves at most while removing gross errors (>= 0).
    """

    method: Method = eqx.field(static=True, default="lm")
    loss: Loss = eqx.field(static=True, default="cauchy")
    loss_scale: float = eqx.field(static=True, default=3.0)
    tol: float = eqx.field(static=True, default=1e-6)
    max_steps: int = eqx.field(static=True, default=100)
    blunder_k: float = eqx.field(static=True, default=BLUNDER_K)
    irls_iterations: int = eqx.field(static=True, default=20)
    irls_tol: float = eqx.field(static=True, default=5e-2)
    remove_blunders: bool = eqx.field(static=True, default=True)
    snooping_rounds: int = eqx.field(static=True, default=30)

    def __check_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.loss not in LOSSES:
            raise ValueError(f"loss must be one of {LOSSES}, got {self.loss!r}")
        if not (isinstance(self.loss_scale, numbers.Real) and self.loss_scale > 0):
            raise ValueError(f"loss_scale must be a positive number, got {self.loss_scale!r}")
        if not (isinstance(self.tol, numbers.Real) and self.tol >= 0 and math.isfinite(self.tol)):
            raise ValueError(f"tol must be a finite number >= 0, got {self.tol!r}")
        if isinstance(self.max_steps, bool) or not isinstance(self.max_steps, numbers.Integral):
            raise ValueError(f"max_steps must be an integer, got {self.max_steps!r}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")
        if not (isinstance(self.blunder_k, numbers.Real) and self.blunder_k > 0):
            raise ValueError(f"blunder_k must be a positive number, got {self.blunder_k!r}")
        for name, low in (("irls_iterations", 1), ("snooping_rounds", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
        if not (isinstance(self.irls_tol, numbers.Real) and self.irls_tol > 0):
            raise ValueError(f"irls_tol must be a positive number, got {self.irls_tol!r}")


DEFAULT_SOLVER = SolverConfig()
"""The default settings: Levenberg-Marquardt, Cauchy loss at 3 sigma (IRLS), ``tol`` 1e-6, 100
steps per solve, gross errors removed by data snooping."""
