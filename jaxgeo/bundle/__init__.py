"""Bundle block adjustment: observations -> problem -> build -> Schur LM solve -> covariance ->
result and report -> export.

``jaxgeo.adjust`` (tables in, :class:`AdjustResult` out; :mod:`.adjustment`) is the one-call
entry point. The stages, each a module: :mod:`.observations` and :mod:`.problem` (the arrays),
:mod:`.build` (checks, grouping, initial points, priors), :mod:`.solve` (the pure, jittable,
vmappable solve; :mod:`.lm` its solver, :mod:`.schur` the steps' linear algebra, :mod:`.batch`
and :mod:`.lanes` many problems in one call, :mod:`.covariance` the cofactors and singularity
test, :mod:`.diagnose` the host-side naming of undetermined unknowns), :mod:`.result`,
:mod:`.report`, :mod:`.export`; :mod:`.config` the solver settings, :mod:`.errors` the errors
and :class:`RESULTS`. The functions ``build`` and ``solve`` live in their modules
(``jaxgeo.bundle.build.build``, ``jaxgeo.bundle.solve.solve``), never in this namespace, so
that ``import jaxgeo.bundle.solve`` is always the module.
"""

from .adjustment import BIAS_CHOICES as BIAS_CHOICES
from .adjustment import adjust as adjust
from .adjustment import with_bias as with_bias
from .build import Setup as Setup
from .config import SolverConfig as SolverConfig
from .errors import RESULTS as RESULTS
from .errors import AdjustmentError as AdjustmentError
from .errors import NotConvergedWarning as NotConvergedWarning
from .errors import PoorFitWarning as PoorFitWarning
from .errors import SingularNormalEquations as SingularNormalEquations
from .errors import TooFewControlPoints as TooFewControlPoints
from .problem import Problem as Problem
from .report import AccuracyReport as AccuracyReport
from .report import accuracy as accuracy
from .report import direct_georeferencing as direct_georeferencing
from .report import format_reports as format_reports
from .result import AdjustResult as AdjustResult
from .result import finish as finish
from .solve import Solution as Solution
