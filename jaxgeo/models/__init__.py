"""Sensor models: each an equinox Module with ``project`` and ``localize`` (:mod:`.base`)."""

from .affine3d import Affine3D as Affine3D
from .base import AbstractMultiImageModel as AbstractMultiImageModel
from .base import AbstractSensorModel as AbstractSensorModel
from .bias import BIAS_KINDS as BIAS_KINDS
from .bias import AbstractBias as AbstractBias
from .bias import Affine as Affine
from .bias import Biased as Biased
from .bias import Shift as Shift
from .bias import ShiftDrift as ShiftDrift
from .ephemeris import EphemerisModel as EphemerisModel
from .ephemeris import gmst_rad as gmst_rad
from .kepler import KeplerCamera as KeplerCamera
from .kepler import KeplerImage as KeplerImage
from .kepler import KeplerSequence as KeplerSequence
from .metadata import SceneMetadata as SceneMetadata
from .newton import NewtonSolution as NewtonSolution
from .newton import newton_root as newton_root
from .pushbroom import GenericPushbroom as GenericPushbroom
from .rpc import RPC as RPC
from .rpc_fit import RPCFitReport as RPCFitReport
from .rpc_fit import fit_rpc as fit_rpc
from .rpc_fit import fit_rpcs as fit_rpcs
from .spline import Spline as Spline
from .spline import SplineObservations as SplineObservations
