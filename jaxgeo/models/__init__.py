"""Sensor models: each an equinox Module with ``project`` and ``localize`` (:mod:`._base`)."""

from ._affine3d import Affine3D as Affine3D
from ._base import AbstractMultiImageModel as AbstractMultiImageModel
from ._base import AbstractSensorModel as AbstractSensorModel
from ._bias import AbstractBias as AbstractBias
from ._bias import AffineBias as AffineBias
from ._bias import Biased as Biased
from ._bias import ShiftBias as ShiftBias
from ._bias import ShiftDriftBias as ShiftDriftBias
from ._dem import AbstractDEM as AbstractDEM
from ._dem import DEMGrid as DEMGrid
from ._dem import DEMStatus as DEMStatus
from ._dem import localize_on_dem as localize_on_dem
from ._ephemeris import EphemerisModel as EphemerisModel
from ._jitter import JitterBias as JitterBias
from ._kepler import KeplerSequence as KeplerSequence
from ._metadata import SceneMetadata as SceneMetadata
from ._pushbroom import GenericPushbroom as GenericPushbroom
from ._rpc import RPC as RPC
from ._rpc_fit import RPCFitReport as RPCFitReport
from ._rpc_fit import fit_rpc as fit_rpc
from ._rpc_fit import fit_rpcs as fit_rpcs
from ._rpc_fit import localize_points as localize_points
from ._rpc_fit import project_points as project_points
from ._spline import Spline as Spline
