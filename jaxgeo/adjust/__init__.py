"""Bundle block adjustment: observations, the structured solver, accuracy reports.

``adjust`` (tables in, :class:`AdjustResult` out) is the entry point; ``core.solve`` is the
same adjustment as a pure function of arrays (jit, vmap, grad).
"""

from .core import Solution as Solution
from .core import solve as solve_problem  # noqa: F401 (the module name solve is taken)
from .errors import AdjustmentError as AdjustmentError
from .errors import NotConvergedWarning as NotConvergedWarning
from .errors import SingularNormalEquations as SingularNormalEquations
from .errors import TooFewControlPoints as TooFewControlPoints
from .params import default_filter as default_filter
from .problem import Problem as Problem
from .report import AccuracyReport as AccuracyReport
from .report import accuracy as accuracy
from .report import direct_georeferencing as direct_georeferencing
from .report import format_reports as format_reports
from .setup import Setup as Setup
from .setup import build as build
from .solve import AdjustResult as AdjustResult
from .solve import adjust as adjust
from .solve import with_bias as with_bias
