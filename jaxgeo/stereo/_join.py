"""Tie points of several pairs joined into multi-image points (one ground point per keypoint)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JoinedTies:
    """Multi-image points from pairwise ties (:func:`join_ties`): per observation its
    ``point`` index ``(m,)``, ``image`` index ``(m,)`` and ``xy`` ``(m, 2)`` px; ``n_views``
    ``(n_points,)`` images per point; ``n_conflicting`` groups of ties dropped because they
    reach two positions in one image."""

    point: np.ndarray
    image: np.ndarray
    xy: np.ndarray
    n_views: np.ndarray
    n_conflicting: int


def join_ties(pairs: Sequence[tuple[int, int, np.ndarray, np.ndarray]]) -> JoinedTies:
    """Join the ties of several pairs ``(image_a, image_b, xy_a (n, 2), xy_b (n, 2))`` into
    points: ties that share a keypoint (the same image and position, to 1e-3 px: the keypoints
    of one detection per image) are one ground point seen in every image they reach, which
    ties the pairs' heights together in an adjustment (pairwise points leave each pair's
    height datum free). A group reaching two positions in one image is inconsistent: dropped.
    """
    keys: dict[tuple[int, float, float], int] = {}
    edges = []
    for ia, ib, xa, xb in pairs:
        for pa, pb in zip(np.round(xa, 3), np.round(xb, 3), strict=True):
            na = keys.setdefault((int(ia), float(pa[0]), float(pa[1])), len(keys))
            nb = keys.setdefault((int(ib), float(pb[0]), float(pb[1])), len(keys))
            edges.append((na, nb))
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(keys)
    if n == 0:
        empty = np.zeros(0, int)
        return JoinedTies(empty, empty, np.zeros((0, 2)), empty, 0)
    e = np.asarray(edges, dtype=int).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    node = np.array([(k[0], k[1], k[2]) for k in keys])  # insertion order = node index
    image = node[:, 0].astype(int)
    # a group is consistent when no image appears twice in it
    per_image = np.unique(np.column_stack([label, image]), axis=0)
    size = np.bincount(label)
    views = np.bincount(per_image[:, 0], minlength=size.size)
    good = views == size
    keep = good[label]
    _, point = np.unique(label[keep], return_inverse=True)
    order = np.lexsort((image[keep], point))
    return JoinedTies(
        point=point[order],
        image=image[keep][order],
        xy=node[keep][order, 1:],
        n_views=size[good],
        n_conflicting=int((~good).sum()),
    )
