"""Level 1 of the full-strip adjustment (003_ s. 6 and 8): its observations and ground points.

The bundle adjustment of all sub-scenes at once sees the formed tie points (:mod:`._ties`) in the
overlaps of adjacent sub-scenes, the tie points the user measured (points of ``observations.csv``
without ground coordinates, seen in two sub-scenes or more) and the GCPs where they exist. A tie
is seen along (nearly) the same ray in both sub-scenes, so its height is not determined by
intersection: every tie gets a height-only ground observation ``(inf, inf, sigma_h)`` from a DEM
(or one mean height with a wide sigma; the bias estimates barely depend on it, since both rays
move together).
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from ..io import GroundPoints, Observations
from ..models import localize_points
from ._config import TieConfig, TieHeight
from ._delivery import Strip
from ._errors import MeasuredTieWarning
from ._ties import StripTies, strip_ties


@dataclasses.dataclass(frozen=True)
class Level1Input:
    """Level-1 observations (formed ties first, then GCP measurements, then measured ties) and
    ground points (GCPs, then the height priors of the formed and of the measured ties);
    ``tie_ids`` (t,), ``tie_lonlath`` (t, 3) the formed ties' ids and initial positions;
    ``measured_ids`` the measured ties used (in the order of their priors)."""

    observations: Observations
    ground: GroundPoints
    ties: StripTies
    tie_ids: tuple[str, ...]
    tie_lonlath: np.ndarray
    measured_ids: tuple[str, ...] = ()


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


def measured_ties(strip: Strip) -> tuple[tuple[str, ...], StripTies, list[int]]:
    """The user's tie points: the observations of points without ground coordinates, as
    ``(ids, StripTies, rows)`` (``point`` indexes ``ids``; ``pair`` the first sub-scene of each;
    ``rows`` the strip's observation rows, in the order of ``StripTies``). A
    point measured in one sub-scene only determines nothing: it is left out with a
    :class:`~._errors.MeasuredTieWarning` naming it."""
    o = strip.observations
    known = set(strip.ground.ids)
    scene = {n: k for k, n in enumerate(strip.names)}
    rows: dict[str, list[int]] = {}
    for i, p in enumerate(o.point_ids):
        if p not in known:
            rows.setdefault(p, []).append(i)
    once = {p for p, r in rows.items() if len({o.images[i] for i in r}) < 2}
    if once:
        where = strip.files.observations if strip.files is not None else "the observations"
        named = ", ".join(map(repr, sorted(once)[:5])) + (", ..." if len(once) > 5 else "")
        warnings.warn(
            f"{where}: {len(once)} point(s) without ground coordinates measured in one sub-scene "
            f"only ({named}): left out (a tie point needs two sub-scenes)",
            MeasuredTieWarning,
            stacklevel=3,
        )
    ids = tuple(p for p in rows if p not in once)  # first-seen order
    sel = [i for p in ids for i in rows[p]]
    point = np.array([k for k, p in enumerate(ids) for _ in rows[p]], dtype=int)
    scenes = np.array([scene[o.images[i]] for i in sel], dtype=int)
    first = np.full(len(ids), np.iinfo(int).max)
    np.minimum.at(first, point, scenes)
    return ids, StripTies(point, scenes, o.xy[sel], first), sel


def level1_input(
    strip: Strip, config: TieConfig | None = None, use_gcps: bool = True
) -> Level1Input:
    """Form the ties as ``config`` says and assemble the level-1 tables (GCPs only with
    ``use_gcps``; the measured ties with the formed ones' height priors; check points are left
    out: they are evaluated by mono-plotting afterwards)."""
    config = TieConfig() if config is None else config
    seed = config.seed if config.layout == "random" else None
    ties = strip_ties(strip.scenes, config.per_pair, margin_px=config.margin_px, seed=seed)
    tie_height = config.height
    width = len(str(ties.n_ties))
    tie_ids = tuple(f"tie_{p:0{width}d}" for p in range(ties.n_ties))
    m_ids, m_ties, m_rows = measured_ties(strip)
    taken = set(tie_ids) & (set(strip.ground.ids) | set(m_ids))
    if taken:
        where = f"{strip.files.observations}: " if strip.files is not None else ""
        raise ValueError(
            f"{where}point ids {sorted(taken)[:5]} clash with the ids of the formed ties "
            "('tie_<n>'): rename them"
        )
    lonlath = _tie_positions(strip, ties, tie_height)
    m_lonlath = _tie_positions(strip, m_ties, tie_height)

    gcps = strip.ground.select("gcp") if use_gcps else strip.ground.select("__none__")
    gcp_set = set(gcps.ids)
    o = strip.observations
    keep = [i for i, p in enumerate(o.point_ids) if p in gcp_set]
    observations = Observations(
        tuple(tie_ids[p] for p in ties.point)
        + tuple(o.point_ids[i] for i in keep)
        + tuple(o.point_ids[i] for i in m_rows),
        tuple(strip.names[s] for s in ties.scene)
        + tuple(o.images[i] for i in keep)
        + tuple(o.images[i] for i in m_rows),
        np.concatenate([ties.xy, o.xy[keep], o.xy[m_rows]]),
        np.concatenate(
            [np.full(len(ties.point), float(config.sigma_px)), o.sigma_px[keep], o.sigma_px[m_rows]]
        ),
    )
    n_prior = ties.n_ties + len(m_ids)
    prior = np.tile([np.inf, np.inf, float(config.height_sigma_m)], (n_prior, 1))
    ground = GroundPoints(
        gcps.ids + tie_ids + m_ids,
        np.concatenate([gcps.lonlath, lonlath, m_lonlath]),
        gcps.role + ("gcp",) * n_prior,
        np.concatenate([gcps.sigma_m, prior]),
    )
    return Level1Input(observations, ground, ties, tie_ids, lonlath, m_ids)


def _tie_positions(strip: Strip, ties: StripTies, tie_height: TieHeight) -> np.ndarray:
    """Initial ``(t, 3)`` positions of ``ties``, from their first observation at their prior
    height (a DEM's: localised again at the DEM height, the initial position matters)."""
    lonlath = _localize_ties(strip, ties, _first_guess_h(strip, tie_height))
    if not ties.n_ties:
        return lonlath
    h = tie_heights(lonlath[:, :2], tie_height, strip)
    if callable(tie_height):
        lonlath = _localize_ties(strip, ties, h)
    lonlath[:, 2] = h
    return lonlath


def _first_guess_h(strip: Strip, tie_height: TieHeight) -> float:
    if callable(tie_height) or tie_height is None:
        return float(tie_heights(np.zeros((1, 2)), None, strip)[0])
    return float(tie_height)
