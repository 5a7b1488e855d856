"""Tie points between adjacent sub-scenes of one strip, from their known line offsets (003_ s. 8).

Sub-scenes are cut from one continuous pushbroom strip: sub-scene ``k`` holds strip lines
``offset_k .. offset_k + n_rows_k - 1``. A pixel of the strip seen in two overlapping sub-scenes
is the same ground point, so a tie is *formed*, not matched: strip pixel ``(x, L)`` is observed at
``(x, L - offset_k)`` in scene ``k`` and ``(x, L - offset_{k+1})`` in scene ``k+1``. This works over
water, desert and cloud alike, and costs nothing.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from ._delivery import SubScene


@dataclasses.dataclass(frozen=True)
class StripTies:
    """Tie observations: ``point`` (m,) tie index, ``scene`` (m,) sub-scene index, ``xy`` (m, 2) px.

    ``pair`` (n_ties,) the index ``k`` of the pair (k, k+1) each tie joins.
    """

    point: np.ndarray
    scene: np.ndarray
    xy: np.ndarray
    pair: np.ndarray

    @property
    def n_ties(self) -> int:
        return len(self.pair)


def overlap_lines(a: SubScene, b: SubScene) -> tuple[int, int]:
    """Strip lines ``[first, last]`` seen by both sub-scenes (empty if ``first > last``)."""
    first = max(a.line_offset, b.line_offset)
    last = min(a.line_offset + a.n_rows, b.line_offset + b.n_rows) - 1
    return first, last


def strip_ties(
    scenes: Sequence[SubScene],
    per_pair: int = 50,
    margin_px: float = 2.0,
    seed: int | None = None,
) -> StripTies:
    """Form ``per_pair`` tie points in the overlap of every adjacent pair of sub-scenes.

    Ties lie on a regular grid (about ``per_pair`` nodes, as square as the overlap allows, at
    least three rows along track from 9 ties on) ``margin_px`` inside the overlap, or at
    uniform random positions when ``seed`` is given.
    Raises a ``ValueError`` naming the pair when two adjacent sub-scenes do not overlap.
    """
    if per_pair < 1:
        raise ValueError(f"per_pair must be >= 1, got {per_pair}")
    rng = None if seed is None else np.random.default_rng(seed)
    points, scene_idx, xy, pairs = [], [], [], []
    n_tie = 0
    for k in range(len(scenes) - 1):
        a, b = scenes[k], scenes[k + 1]
        first, last = overlap_lines(a, b)
        col_lo = max(a.col_offset, b.col_offset)
        col_hi = min(a.col_offset + a.n_cols, b.col_offset + b.n_cols) - 1
        if last - first < 2 * margin_px or col_hi - col_lo < 2 * margin_px:
            raise ValueError(
                f"sub-scenes {a.name!r} and {b.name!r} do not overlap (strip lines "
                f"{a.line_offset}..{a.line_offset + a.n_rows - 1} and "
                f"{b.line_offset}..{b.line_offset + b.n_rows - 1}): no tie points can be formed"
            )
        lo = np.array([col_lo + margin_px, first + margin_px])
        hi = np.array([col_hi - margin_px, last - margin_px])
        if rng is None:
            aspect = (hi[0] - lo[0]) / max(hi[1] - lo[1], 1e-9)
            # at least three rows across the overlap (when there are enough ties): a single row
            # leaves the along-track terms of the affine biases undetermined
            min_rows = 3 if per_pair >= 9 else 2 if per_pair >= 4 else 1
            n_rows = max(min_rows, min(per_pair, round(math.sqrt(per_pair / aspect))))
            n_cols = math.ceil(per_pair / n_rows)
            gx, gy = np.meshgrid(
                np.linspace(lo[0], hi[0], n_cols), np.linspace(lo[1], hi[1], n_rows)
            )
            strip_xy = np.stack([gx.ravel(), gy.ravel()], axis=-1)[:per_pair]
        else:
            strip_xy = lo + rng.uniform(size=(per_pair, 2)) * (hi - lo)
        ids = n_tie + np.arange(len(strip_xy))
        n_tie += len(strip_xy)
        for j, sc in ((k, a), (k + 1, b)):
            points.append(ids)
            scene_idx.append(np.full(len(ids), j))
            xy.append(strip_xy - [sc.col_offset, sc.line_offset])
        pairs.append(np.full(len(ids), k))
    if not pairs:
        raise ValueError("a strip needs at least two sub-scenes to form tie points")
    return StripTies(
        point=np.concatenate(points),
        scene=np.concatenate(scene_idx),
        xy=np.concatenate(xy).astype(float),
        pair=np.concatenate(pairs),
    )
