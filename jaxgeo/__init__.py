"""jaxgeo: differentiable sensor models and bundle adjustment for satellite imagery.

Conventions: ground ``(lon_deg, lat_deg, h_m)`` on WGS84 (ellipsoidal height), ECEF in metres,
image ``(x, y) = (col, row)`` px with integer values at pixel centres, float64 everywhere.

The public names below are imported on first use (PEP 562), so that ``jaxgeo --help`` and
``jaxgeo --version`` start without importing jax.
"""

import importlib
import importlib.metadata

from ._runtime.jaxconfig import configure as _configure_jax
from .errors import JaxgeoWarning as _JaxgeoWarning

# float64 everywhere and the persistent compilation cache, before any submodule imports jax
# (environment variables jax reads when it starts; jax.config if it already has)
_configure_jax(_JaxgeoWarning)

try:
    __version__ = importlib.metadata.version("jaxgeo")
except importlib.metadata.PackageNotFoundError:  # a source tree on sys.path, not installed
    __version__ = "unknown (not installed)"

_EXPORTS = {
    "jaxgeo.bundle": ("AccuracyReport", "AdjustResult", "AdjustSettings", "adjust"),
    "jaxgeo.lsq": ("SolverConfig",),
    "jaxgeo.intersect": ("IntersectResult",),
    "jaxgeo.io": ("read_metadata", "read_rpc", "write_geotiff_rpc", "write_rpb",
                  "write_rpc_text"),
    "jaxgeo.models": ("RPC", "AbstractSensorModel", "AbstractMultiImageModel", "AffineBias",
                      "Affine3D", "Biased", "EphemerisModel", "GenericPushbroom", "SceneMetadata",
                      "KeplerSequence", "ShiftBias", "ShiftDriftBias", "Spline", "fit_rpc"),
}  # fmt: skip
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}
# ``jaxgeo.intersect`` is the intersection module (``jaxgeo.intersect.intersect`` the function):
# no function shadows a module of the package
_SUBMODULES = (
    "geodesy", "rotations", "errors", "models", "lsq", "intersect", "io", "bundle", "strip",
    "tiles", "ortho", "stereo", "coreg", "simulate", "report", "cli",
)  # fmt: skip


def __getattr__(name: str):
    if name in _WHERE:
        value = getattr(importlib.import_module(_WHERE[name]), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted({*globals(), *_WHERE, *_SUBMODULES})
