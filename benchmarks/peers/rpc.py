"""The RPC peers of the projection and localisation studies besides GDAL
(``benchmarks.speed.projection``, ``benchmarks.speed.localization``): CNES shareloc and rpcm,
each optional (a peer that is not installed is reported, not estimated).

    pip install shareloc            # numba kernels (its wheel pins affine <= 3.0.0)
    pip install --no-deps rpcm      # its srtm4 dependency does not build here; projection and
                                    # localisation at given heights do not use it

shareloc 0.3.0's wheel also installs a top-level ``tests`` package, which shadows jaxgeo's own
(pytest then fails to import ``tests.typecheck``): install the peers in another environment,
or delete ``site-packages/tests`` after installing.

Pixel conventions: shareloc's ``(row, col)`` are ours + 0.5 (GDAL's); rpcm's ``(col, row)`` are
ours. Both read the RPC from the GeoTIFF's tags, as GDAL does.
"""

from __future__ import annotations

import importlib.metadata
import sys
import types

import numpy as np


def load_shareloc(tif: str):
    """shareloc's ``GeoModel(tif, "RPC")``, or the reason it is unavailable (a string)."""
    try:
        from shareloc.geomodels import GeoModel
    except ImportError as err:
        return f"not installed ({err})"
    return GeoModel(str(tif), "RPC")


def load_rpcm(tif: str):
    """rpcm's ``RPCModel`` of ``tif``, or the reason it is unavailable (a string)."""
    # rpcm imports srtm4 (SRTM heights for localisation without a height) at import time only
    sys.modules.setdefault("srtm4", types.ModuleType("srtm4"))
    try:
        import rpcm
    except ImportError as err:
        return f"not installed ({err})"
    return rpcm.rpc_from_geotiff(str(tif))


def load(tif: str, kind: str) -> dict:
    """``{peer: (model or the reason it is unavailable, its kind function)}``, ``kind``
    ``"project"`` or ``"localize"``."""
    fns = {
        "project": {"shareloc": shareloc_project, "rpcm": rpcm_project},
        "localize": {"shareloc": shareloc_localize, "rpcm": rpcm_localize},
    }[kind]
    return {
        "shareloc": (load_shareloc(tif), fns["shareloc"]),
        "rpcm": (load_rpcm(tif), fns["rpcm"]),
    }


def versions(peers: dict) -> dict[str, str]:
    """Each peer's installed version, or the reason it is unavailable."""
    return {
        name: model if isinstance(model, str) else importlib.metadata.version(name)
        for name, (model, _) in peers.items()
    }


def shareloc_project(model, ground: np.ndarray) -> np.ndarray:
    row, col, _ = model.inverse_loc(ground[:, 0], ground[:, 1], ground[:, 2])
    return np.stack([np.asarray(col), np.asarray(row)], axis=-1) - 0.5


def shareloc_localize(model, xy: np.ndarray, h: np.ndarray) -> np.ndarray:
    return np.asarray(model.direct_loc_h(xy[:, 1] + 0.5, xy[:, 0] + 0.5, h))


def rpcm_project(model, ground: np.ndarray) -> np.ndarray:
    col, row = model.projection(ground[:, 0], ground[:, 1], ground[:, 2])
    return np.stack([col, row], axis=-1)


def rpcm_localize(model, xy: np.ndarray, h: np.ndarray) -> np.ndarray:
    lon, lat = model.localization(xy[:, 0], xy[:, 1], h)
    return np.stack([lon, lat, h], axis=-1)
