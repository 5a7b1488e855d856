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

from ._adjustment import BIAS_CHOICES as BIAS_CHOICES
from ._adjustment import adjust as adjust
from ._adjustment import bias_prior_sigma as bias_prior_sigma
from ._adjustment import image_lines as image_lines
from ._adjustment import with_bias as with_bias
from ._errors import AdjustmentError as AdjustmentError
from ._errors import NotConvergedWarning as NotConvergedWarning
from ._errors import PoorFitWarning as PoorFitWarning
from ._errors import SingularNormalEquations as SingularNormalEquations
from ._errors import TooFewControlPoints as TooFewControlPoints
from ._export import RPCOutputs as RPCOutputs
from ._export import adjusted_rpc as adjusted_rpc
from ._export import check_out_dir as check_out_dir
from ._export import output_paths as output_paths
from ._export import probe_folder as probe_folder
from ._files import RELATIVE_PRIOR_MATRIX as RELATIVE_PRIOR_MATRIX
from ._files import RELATIVE_PRIOR_SHIFT_PX as RELATIVE_PRIOR_SHIFT_PX
from ._files import FileAdjustment as FileAdjustment
from ._files import adjust_files as adjust_files
from ._files import image_inputs as image_inputs
from ._files import sensor_image as sensor_image
from ._prepare import Prepared as Prepared
from ._prepare import prepare as prepare
from ._report import AccuracyReport as AccuracyReport
from ._report import accuracy as accuracy
from ._report import direct_georeferencing as direct_georeferencing
from ._report import enu_errors as enu_errors
from ._report import format_reports as format_reports
from ._result import AdjustResult as AdjustResult
from ._result import make_result as make_result
from ._settings import AdjustSettings as AdjustSettings
from ._settings import JitterSettings as JitterSettings
from ._snooping import MAX_REMOVED_FRACTION as MAX_REMOVED_FRACTION
from ._snooping import ROBUST_FRACTION as ROBUST_FRACTION
from ._snooping import over_limits as over_limits
from ._snooping import removal_cap as removal_cap
from ._snooping import snoop as snoop
from ._snooping import snooping_verdict as snooping_verdict
