"""Stages of :mod:`jaxgeo.models` that other jaxgeo packages use: not the user API (names here
may change without notice); a user imports from ``jaxgeo.models``."""

from ._affine3d import COPLANAR_RTOL as COPLANAR_RTOL
from ._base import nothing as nothing
from ._bias import BIAS_KINDS as BIAS_KINDS
from ._ephemeris import gmst_rad as gmst_rad
from ._jitter import KNOT_SIGMA_PX as KNOT_SIGMA_PX
from ._jitter import PIN_SIGMA_PX as PIN_SIGMA_PX
from ._metadata import SCENE_FLOAT_FIELDS as SCENE_FLOAT_FIELDS
from ._newton import newton_root as newton_root
from ._rpc import TermOrder as TermOrder
from ._rpc import check_rpc as check_rpc
from ._rpc import monomials as monomials
