"""Stereo from images: guided tie points, epipolar rectification for any sensor model, dense
matching (OpenCV SGM), triangulation through the models and DSM rasterisation.

Pipeline entry points: :func:`stereo_pair` (one pair -> 3D points) and :func:`dsm_from_images`
(reference + secondaries -> one DSM grid); each stage's names are public here, from its private
module: matching (``_matching``), rectification (``_rectification``), dense matching
(``_dense``), triangulation (``_triangulation``), rasterisation (``_dsm``), the height sigma
(``_uncertainty``).
"""

from ._dense import SGMSettings as SGMSettings
from ._dense import sgm_disparity as sgm_disparity
from ._dsm import DSM_BANDS as DSM_BANDS
from ._dsm import DSMGrid as DSMGrid
from ._dsm import rasterize as rasterize
from ._dsm import write_dsm as write_dsm
from ._make import make_dsm as make_dsm
from ._make import tiled_dsm as tiled_dsm
from ._match_images import NoTiesError as NoTiesError
from ._match_images import TieResult as TieResult
from ._match_images import match_images as match_images
from ._match_settings import MatchSettings as MatchSettings
from ._matching import epipolar_offsets as epipolar_offsets
from ._matching import guided_matches as guided_matches
from ._matching import sift_features as sift_features
from ._pipeline import dsm_from_images as dsm_from_images
from ._pipeline import stereo_pair as stereo_pair
from ._rectification import epipolar_grids as epipolar_grids
from ._report import DSMReport as DSMReport
from ._settings import DSMSettings as DSMSettings
from ._settings import DSMSettingsError as DSMSettingsError
from ._sgm import SGMMemoryError as SGMMemoryError
from ._ties import TieError as TieError
from ._ties import TieReport as TieReport
from ._ties import TieWarning as TieWarning
from ._ties import tie_points as tie_points
from ._tiled import plan_dsm as plan_dsm
from ._triangulation import StereoError as StereoError
from ._triangulation import los_heights as los_heights
from ._triangulation import triangulate as triangulate
from ._uncertainty import Orientation as Orientation
from ._uncertainty import OrientationError as OrientationError
from ._uncertainty import adjustment_covariance as adjustment_covariance
from ._uncertainty import sigma_calibration as sigma_calibration
