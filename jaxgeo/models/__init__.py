"""Sensor models: each an equinox Module with ``project`` and ``localize``."""

from .base import AbstractSensorModel as AbstractSensorModel
from .bias import AbstractBias as AbstractBias
from .bias import Affine as Affine
from .bias import Biased as Biased
from .bias import Shift as Shift
from .bias import ShiftDrift as ShiftDrift
from .rpc import RPC as RPC

# --- physical models (issue 3) are re-exported below this line ---
