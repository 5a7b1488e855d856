"""A DSM's DEM checked against the images before any tile runs (issue 53, item 2): a DSM takes
from ``--dem`` only the heights it searches, and a DEM in feet or off by hundreds of metres would
make every tile search beside the terrain (few or no heights, no error)."""

from __future__ import annotations

import warnings

import numpy as np

from ..io.internal import dem_against_model, dem_against_ties
from ._ties import MatchSettings, TieError, tie_points
from ._triangulation import StereoError

WINDOW_KEYPOINTS = 1000
"""The reference keypoints (spread, the strongest) of a window searched for its ties' heights
(a few hundred ties give a height range; all of a 512 px window's cost three times as much)."""


def check_dem(models, paths, window, dem, dem_range: tuple[float, float]) -> None:
    """Refuse (:class:`TieError` naming the file) a DEM whose heights ``dem_range`` over the
    footprint of the DSM are not the terrain of these images: outside the reference model's
    validity range (:func:`jaxgeo.io.internal.dem_against_model`), or unlike the heights of
    the tie points of the pair (first, second) in ``window`` ``(col, row, w, h)`` of the
    reference (:func:`jaxgeo.io.internal.dem_against_ties`: a DEM in feet, in another datum,
    off by a constant; one window of tie points, searched over the models' validity range)."""
    why = dem_against_model(dem_range, models[0], str(dem.path), str(paths[0]))
    if why is None:
        ground = window_tie_ground(models, paths, window)
        if ground is None:  # no texture there: nothing to compare
            return
        why = dem_against_ties(ground[:, 2], dem.sample(ground[:, :2]), str(dem.path))
    if why is not None:
        raise TieError(f"{why}; a DSM searches the heights the DEM gives: give the right DEM, "
                       "--heights, or no --dem")  # fmt: skip


def window_tie_ground(models, paths, window) -> np.ndarray | None:
    """The ground points ``(n, 3)`` (lon, lat, h) of the tie points of the pair (first, second)
    in ``window`` ``(col, row, w, h)`` of the reference, quietly; ``None`` where there are too
    few (no texture, water, clouds)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ties = tie_points(models[0], models[1], paths[0], paths[1],
                              MatchSettings(roi=window, keypoints=WINDOW_KEYPOINTS))  # fmt: skip
    except (TieError, StereoError):
        return None
    return np.asarray(ties.ground)
