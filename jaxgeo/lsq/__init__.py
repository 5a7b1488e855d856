"""The least-squares engine: structured Gauss-Newton / Levenberg-Marquardt on arrays, no files.

``solve(problem, SolverConfig())`` adjusts one :class:`Problem` (sensor-model groups, image and
ground observations, ground points) and returns a :class:`Solution` (unknowns, covariance,
residuals, s0, :class:`RESULTS`); it is jittable, vmappable and differentiable (the implicit
derivative of the M-estimate). ``solve_batch`` adjusts many problems of one structure in one
call. Pure arrays in and out: the host-side workflow (tables, checks, names, reports, files) is
:mod:`jaxgeo.bundle`, which, like :mod:`jaxgeo.strip`, imports only the names below and the
engine's stages in :mod:`jaxgeo.lsq.internal` (not the user API).

How the pieces fit (optimistix' pattern: settings, state and solution apart):

- :class:`Problem` (with :class:`ModelGroup`, :class:`ImageObs`, :class:`GroundObs`) holds the
  arrays; :func:`make_structure` the index arrays of who observes what.
- :class:`SolverConfig` the settings (method, loss, tolerances).
- :class:`StructuredGaussNewton`, an ``optimistix.AbstractLeastSquaresSolver`` whose steps
  eliminate the 3x3 point blocks (Schur complement; block-banded for strips) and whose
  robust losses are a reweighting phase of the same solve.
- :class:`Solution` and :class:`RESULTS` (errors as data, raised only with ``throw=True``).
"""

from ._band import Band as Band
from ._batch import solve_batch as solve_batch
from ._batch import solve_batch_distributed as solve_batch_distributed
from ._batch import with_xy_batch as with_xy_batch
from ._config import LOSSES as LOSSES
from ._config import SolverConfig as SolverConfig
from ._covariance import Covariance as Covariance
from ._covariance import cofactors as cofactors
from ._lm import StructuredGaussNewton as StructuredGaussNewton
from ._loss import rho as rho
from ._observations import GroundObs as GroundObs
from ._observations import ImageObs as ImageObs
from ._problem import ModelGroup as ModelGroup
from ._problem import Problem as Problem
from ._problem import Structure as Structure
from ._problem import make_structure as make_structure
from ._residuals import residuals as residuals
from ._results import RESULTS as RESULTS
from ._solve import Solution as Solution
from ._solve import blocks_at as blocks_at
from ._solve import initial_unknowns as initial_unknowns
from ._solve import solve as solve
from ._solve import solve_kept as solve_kept
from ._solve import unit_scales as unit_scales
