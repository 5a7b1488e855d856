"""Stages of :mod:`jaxgeo.bundle` that other jaxgeo packages use: not the user API (names here
may change without notice); a user imports from ``jaxgeo.bundle``."""

from ._adjustment import BIAS_CHOICES as BIAS_CHOICES
from ._export import check_out_dir as check_out_dir
from ._export import probe_folder as probe_folder
from ._files import image_inputs as image_inputs
from ._files import sensor_image as sensor_image
from ._report import enu_errors as enu_errors
from ._report import format_reports as format_reports
from ._result import make_result as make_result
from ._snooping import MAX_REMOVED_FRACTION as MAX_REMOVED_FRACTION
from ._snooping import ROBUST_FRACTION as ROBUST_FRACTION
from ._snooping import snoop as snoop
