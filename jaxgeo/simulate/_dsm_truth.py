"""A DSM against the true surface of a simulated scene (table 8 of 002_: min, max, RMSE, LE90).

Every cell of the DSM grid has a true height: the terrain at the cell centre. A cell is
*evaluated* when that true ground point is inside every image and seen by it (the first
intersection of the pixel's line of sight with the terrain is the point itself: not occluded);
``dh = dsm - truth`` over the evaluated cells that the DSM fills. LE90 is the 90th percentile of
``|dh|`` (the absolute linear error at 90 %); ``fill`` the share of evaluated cells filled.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..models import AbstractSensorModel
from ..stereo import DSMGrid
from ._render import localize_on_terrain
from ._terrain import Terrain


def cell_truth(dsm: DSMGrid, terrain: Terrain) -> np.ndarray:
    """``(rows, cols, 3)`` lon/lat/h of the true surface at the centres of the DSM's cells."""
    import pyproj

    rows, cols = dsm.height.shape
    x = dsm.x0 + dsm.res_m * (np.arange(cols) + 0.5)
    y = dsm.y0 - dsm.res_m * (np.arange(rows) + 0.5)
    xx, yy = np.meshgrid(x, y)
    tr = pyproj.Transformer.from_crs(dsm.epsg, 4326, always_xy=True)
    lon, lat = tr.transform(xx, yy)
    lonlat = np.stack([np.asarray(lon), np.asarray(lat)], -1)
    return np.concatenate([lonlat, terrain.height_np(lonlat)[..., None]], -1)


def visible(
    models: Sequence[AbstractSensorModel],
    shapes: Sequence[tuple[int, int]],
    terrain: Terrain,
    ground: np.ndarray,
    margin_px: float = 2.0,
    tol_m: float = 0.05,
) -> np.ndarray:
    """``(n,)`` whether each ground point ``(n, 3)`` lies inside every image (``margin_px`` in
    from its edges; ``shapes`` ``(rows, cols)``) and is the first terrain point on its line of
    sight there (within ``tol_m`` horizontally)."""
    ok = np.all(np.isfinite(ground), axis=1)
    for model, (rows, cols) in zip(models, shapes, strict=True):
        xy = np.asarray(model.project(ground))
        inside = ok & np.all(
            (xy >= margin_px) & (xy <= np.array([cols - 1, rows - 1]) - margin_px), axis=1
        )
        seen = np.zeros_like(ok)
        if inside.any():
            g = localize_on_terrain(model, terrain, xy[inside])
            d = g[:, :2] - ground[inside, :2]
            dist = np.hypot(d[:, 0] * 111320.0 * np.cos(np.deg2rad(ground[inside, 1])),
                            d[:, 1] * 110540.0)  # fmt: skip
            seen[inside] = np.nan_to_num(dist, nan=np.inf) < tol_m
        ok = ok & seen
    return ok


def height_errors(
    dsm: DSMGrid,
    terrain: Terrain,
    models: Sequence[AbstractSensorModel],
    shapes: Sequence[tuple[int, int]],
    gsd_m: float,
) -> dict:
    """Table 8 of 002_ for ``dsm``: ``min_m``, ``max_m``, ``mean_m``, ``rmse_m``, ``le90_m``
    of ``dh = dsm - truth`` over the evaluated cells (module docstring), the same in GSDs
    (``*_gsd``), ``n_cells`` evaluated, ``n_filled`` and ``fill``. ``models`` are the true
    models of the images (for the visibility test)."""
    truth = cell_truth(dsm, terrain)
    flat = truth.reshape(-1, 3)
    evaluated = visible(models, shapes, terrain, flat).reshape(dsm.height.shape)
    filled = evaluated & np.isfinite(dsm.height)
    dh = (dsm.height.astype(float) - truth[..., 2])[filled]
    out = {"n_cells": int(evaluated.sum()), "n_filled": int(filled.sum())}
    out["fill"] = out["n_filled"] / max(out["n_cells"], 1)
    if dh.size == 0:
        return out | {k: float("nan") for k in ("min_m", "max_m", "mean_m", "rmse_m", "le90_m")}
    stats = {
        "min_m": float(dh.min()),
        "max_m": float(dh.max()),
        "mean_m": float(dh.mean()),
        "rmse_m": float(np.sqrt(np.mean(dh**2))),
        "le90_m": float(np.percentile(np.abs(dh), 90)),
    }
    out |= stats
    out |= {k.replace("_m", "_gsd"): v / gsd_m for k, v in stats.items()}
    return {k: round(v, 4) if isinstance(v, float) else v for k, v in out.items()}
