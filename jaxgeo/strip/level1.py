"""Level 1 of the full-strip adjustment (003_ s. 6 and 8): its observations and ground points.

The bundle adjustment of all sub-scenes at once sees the formed tie points (:mod:`.ties`) in the
overlaps of adjacent sub-scenes and the GCPs where they exist. A tie is seen along (nearly) the
same ray in both sub-scenes, so its height is not determined by intersection: every tie gets a
height-only ground observation ``(inf, inf, sigma_h)`` from a DEM (or one mean height with a
wide sigma; the bias estimates barely depend on it, since both rays move together).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..io import GroundPoints, Observations
from ..models.rpc_fit import localize_points
from .config import TieConfig, TieHeight
from .delivery import Strip
from .ties import StripTies, strip_ties


@dataclasses.dataclass(frozen=True)
class Level1Input:
    """Level-1 observations (ties first, then GCP measurements) and ground points (GCPs, then
    tie height priors); ``tie_ids`` (t,), ``tie_lonlath`` (t, 3) initial tie positions."""

    observations: Observations
    ground: GroundPoints
    ties: StripTies
    tie_ids: tuple[str, ...]
    tie_lonlath: np.ndarray


def tie_heights(lonlat: np.ndarray, tie_height: TieHeight, strip: Strip) -> np.ndarray:
    """Heights (m) of the ties: a DEM callable ``f(lonlat (n, 2)) -> (n,)``, a constant, or
    (``None``) the mean surveyed height of the strip's ground points (RPC height offsets if
    there are none)."""
    if callable(tie_height):
        h = np.asarray(tie_height(np.asarray(lonlat)), dtype=float).reshape(-1)
        if h.shape != (len(lonlat),) or not np.all(np.isfinite(h)):
            raise ValueError(
                f"the tie height function returned {h.shape} values (non-finite: "
                f"{int(np.sum(~np.isfinite(h)))}) for {len(lonlat)} tie points"
            )
        return h
    if tie_height is None:
        if len(strip.ground):
            tie_height = float(np.mean(strip.ground.lonlath[:, 2]))
        else:
            tie_height = float(np.mean([float(r.ground_offset[2]) for r in strip.rpcs.values()]))
    return np.full(len(lonlat), float(tie_height))


def _localize_ties(strip: Strip, ties: StripTies, h: np.ndarray | float) -> np.ndarray:
    """Ground of every tie from its first observation, at ``h`` (scalar or per tie)."""
    first = np.zeros(ties.n_ties, dtype=int)
    first[ties.point[::-1]] = np.arange(len(ties.point))[::-1]
    h = np.broadcast_to(np.asarray(h, dtype=float), (ties.n_ties,))
    out = np.zeros((ties.n_ties, 3))
    for k, name in enumerate(strip.names):
        sel = first[ties.scene[first] == k]
        if sel.size:
            pts = ties.point[sel]
            out[pts] = localize_points(strip.rpcs[name], ties.xy[sel], h[pts])
    return out


def level1_input(
    strip: Strip, config: TieConfig | None = None, use_gcps: bool = True
) -> Level1Input:
    """Form the ties as ``config`` says and assemble the level-1 tables (GCPs only with
    ``use_gcps``; check points are left out: they are evaluated by mono-plotting afterwards)."""
    config = TieConfig() if config is None else config
    seed = config.seed if config.layout == "random" else None
    ties = strip_ties(strip.scenes, config.per_pair, margin_px=config.margin_px, seed=seed)
    tie_height = config.height
    width = len(str(ties.n_ties))
    tie_ids = tuple(f"tie_{p:0{width}d}" for p in range(ties.n_ties))
    taken = set(tie_ids) & set(strip.ground.ids)
    if taken:
        raise ValueError(f"ground point ids {sorted(taken)[:5]} clash with the formed tie ids")
    lonlath = _localize_ties(strip, ties, _first_guess_h(strip, tie_height))
    h = tie_heights(lonlath[:, :2], tie_height, strip)
    if callable(tie_height):  # relocalise at the DEM height: the initial position matters
        lonlath = _localize_ties(strip, ties, h)
    lonlath[:, 2] = h

    gcps = strip.ground.select("gcp") if use_gcps else strip.ground.select("__none__")
    gcp_set = set(gcps.ids)
    o = strip.observations
    keep = [i for i, p in enumerate(o.point_ids) if p in gcp_set]
    observations = Observations(
        tuple(tie_ids[p] for p in ties.point) + tuple(o.point_ids[i] for i in keep),
        tuple(strip.names[s] for s in ties.scene) + tuple(o.images[i] for i in keep),
        np.concatenate([ties.xy, o.xy[keep]]),
        np.concatenate([np.full(len(ties.point), float(config.sigma_px)), o.sigma_px[keep]]),
    )
    prior = np.tile([np.inf, np.inf, float(config.height_sigma_m)], (ties.n_ties, 1))
    ground = GroundPoints(
        gcps.ids + tie_ids,
        np.concatenate([gcps.lonlath, lonlath]),
        gcps.role + ("gcp",) * ties.n_ties,
        np.concatenate([gcps.sigma_m, prior]),
    )
    return Level1Input(observations, ground, ties, tie_ids, lonlath)


def _first_guess_h(strip: Strip, tie_height: TieHeight) -> float:
    if callable(tie_height) or tie_height is None:
        return float(tie_heights(np.zeros((1, 2)), None, strip)[0])
    return float(tie_height)
