"""Stereo from images: guided tie points, epipolar rectification for any sensor model, dense
matching (OpenCV SGM), triangulation through the models and DSM rasterisation.

Pipeline entry points: :func:`stereo_pair` (one pair -> 3D points) and :func:`dsm_from_images`
(reference + secondaries -> one DSM grid); the stages are public modules: :mod:`.matching`,
:mod:`.rectification`, :mod:`.dense`, :mod:`.triangulation`, :mod:`.dsm`.
"""

from .dense import SGMSettings as SGMSettings
from .dense import resample as resample
from .dense import sgm_disparity as sgm_disparity
from .dsm import DSMGrid as DSMGrid
from .dsm import rasterize as rasterize
from .dsm import write_dsm as write_dsm
from .matching import Matches as Matches
from .matching import epipolar_offsets as epipolar_offsets
from .matching import guided_matches as guided_matches
from .matching import sift_features as sift_features
from .pipeline import PairProducts as PairProducts
from .pipeline import dsm_from_images as dsm_from_images
from .pipeline import stereo_pair as stereo_pair
from .rectification import EpipolarGrids as EpipolarGrids
from .rectification import epipolar_grids as epipolar_grids
from .triangulation import disparity_to_matches as disparity_to_matches
from .triangulation import triangulate as triangulate
