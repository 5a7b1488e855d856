"""Bundle block adjustment, the host-side workflow: tables in, :class:`AdjustResult` out.

``jaxgeo.adjust`` (:func:`adjust`) is the one-call entry point; :class:`AdjustSettings` holds
what it adjusts and holds besides the solver (:class:`jaxgeo.lsq.SolverConfig`). The stages,
in the order the data passes them: :func:`prepare` (pre-flight checks naming the image or point
at fault, model groups, initial ground points, priors -> a :class:`Prepared` holding a
:class:`jaxgeo.lsq.Problem`), :func:`jaxgeo.lsq.solve` (the engine: pure arrays), :func:`snoop`
(gross errors: robust loss, w-test, removal), :func:`make_result` (names, statistics, the
undetermined unknowns named), :func:`accuracy` / :func:`format_reports` (the papers' accuracy
reports) and the writers of adjusted models (:func:`check_out_dir`, refitted RPCs beside the
inputs, never over them, :class:`RPCOutputs`). :func:`adjust_files` runs it on files: images
(rasters or model files), OBS/GROUND tables, a DEM.
"""

from ._adjustment import adjust as adjust
from ._adjustment import bias_prior_sigma as bias_prior_sigma
from ._adjustment import with_bias as with_bias
from ._errors import AdjustmentError as AdjustmentError
from ._errors import NotConvergedWarning as NotConvergedWarning
from ._errors import PoorFitWarning as PoorFitWarning
from ._errors import SingularNormalEquations as SingularNormalEquations
from ._errors import TooFewControlPoints as TooFewControlPoints
from ._export import adjusted_rpc as adjusted_rpc
from ._files import FileAdjustment as FileAdjustment
from ._files import adjust_files as adjust_files
from ._prepare import Prepared as Prepared
from ._prepare import prepare as prepare
from ._report import AccuracyReport as AccuracyReport
from ._report import accuracy as accuracy
from ._report import direct_georeferencing as direct_georeferencing
from ._result import AdjustResult as AdjustResult
from ._settings import AdjustSettings as AdjustSettings
from ._settings import JitterSettings as JitterSettings
