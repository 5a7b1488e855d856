"""jaxgeo: differentiable sensor models and bundle adjustment for satellite imagery.

Conventions: ground ``(lon_deg, lat_deg, h_m)`` on WGS84 (ellipsoidal height), ECEF in metres,
image ``(x, y) = (col, row)`` px with integer values at pixel centres, float64 everywhere.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from . import geodesy as geodesy  # noqa: E402
from . import rotations as rotations  # noqa: E402
from . import simulate as simulate  # noqa: E402
from .adjust import AccuracyReport as AccuracyReport  # noqa: E402
from .adjust import AdjustResult as AdjustResult  # noqa: E402
from .adjust import adjust as adjust  # noqa: E402
from .intersect import IntersectResult as IntersectResult  # noqa: E402
from .intersect import intersect as intersect  # noqa: E402
from .io import SceneMetadata as SceneMetadata  # noqa: E402
from .io import read_metadata as read_metadata  # noqa: E402
from .io import read_rpc as read_rpc  # noqa: E402
from .io import write_geotiff_rpc as write_geotiff_rpc  # noqa: E402
from .io import write_rpb as write_rpb  # noqa: E402
from .io import write_rpc_text as write_rpc_text  # noqa: E402
from .models import RPC as RPC  # noqa: E402
from .models import AbstractSensorModel as AbstractSensorModel  # noqa: E402
from .models import Affine as Affine  # noqa: E402
from .models import Affine3D as Affine3D  # noqa: E402
from .models import Biased as Biased  # noqa: E402
from .models import EphemerisModel as EphemerisModel  # noqa: E402
from .models import GenericPushbroom as GenericPushbroom  # noqa: E402
from .models import KeplerSequence as KeplerSequence  # noqa: E402
from .models import Shift as Shift  # noqa: E402
from .models import ShiftDrift as ShiftDrift  # noqa: E402
from .models import Spline as Spline  # noqa: E402
from .models import fit_rpc as fit_rpc  # noqa: E402

__version__ = "0.1.0"
