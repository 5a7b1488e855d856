"""The keypoints of a stereo pair's windows: SIFT at half resolution on the pixels already read,
and the reference window's kept for the next pair of the same tile (no work repeated across a
tile's pairs: the reference window, its stretch and its keypoints are the same for each)."""

from __future__ import annotations

import os

import numpy as np

from ._matching import sift_features, stretch_limits, to_uint8

SIFT_COARSE_MIN_PX, SIFT_LEVEL = 768, 2
"""A window this large (px, both sides) is searched for keypoints at 1 / ``SIFT_LEVEL``."""

_LAST: dict = {}
"""The last reference window read (``key``, ``value``): one per process."""


def window_keypoints(image, origin, limits, most=None):
    """SIFT keypoints (raster px) and descriptors of a window read (``image``, its first pixel
    at ``origin``; ``limits``: its uint8 stretch), at half resolution from
    :data:`SIFT_COARSE_MIN_PX` (what the ties fix needs no finer keypoint; a quarter of the
    cost); a random subset (seeded) of ``most`` when there are more."""
    import cv2

    image8 = to_uint8(image, limits)
    level = SIFT_LEVEL if min(image8.shape) >= SIFT_COARSE_MIN_PX else 1
    if level > 1:  # whole blocks: a size not a multiple of the level would stretch the scale
        h, w = (n - n % level for n in image8.shape)
        image8 = cv2.resize(image8[:h, :w], (w // level, h // level), interpolation=cv2.INTER_AREA)
    xy, desc = sift_features(image8)  # a coarse pixel's centre: that of the block it averages
    xy = (xy + 0.5) * level - 0.5 + np.asarray(origin, dtype=float)
    if most is not None and len(xy) > most:
        pick = np.sort(np.random.default_rng(0).choice(len(xy), most, replace=False))
        xy, desc = xy[pick], desc[pick]
    return xy, desc


def reference_features(path, window, read, most):
    """``(image, limits, features)`` of the reference image ``path`` over ``window = (col, row,
    w, h)``: its pixels (``read(path, window)``), their uint8 stretch (from every other pixel)
    and :func:`window_keypoints` (at most ``most``; a window searched at full resolution with
    the stretch of all its pixels, as :func:`~._matching.sift_features_raster`), kept for the
    next call with the same file (its size and modification time) and window: the next pair of
    a tile. A URL is read each time."""
    try:
        st = os.stat(path)
        key = (os.fspath(path), tuple(int(v) for v in window), st.st_size, st.st_mtime_ns, most)
    except (OSError, TypeError, ValueError):
        key = None
    if key is not None and _LAST.get("key") == key:
        return _LAST["value"]
    image = read(path, window)
    limits = stretch_limits(image[::2, ::2])
    coarse = min(image.shape) >= SIFT_COARSE_MIN_PX
    sift_limits = limits if coarse else stretch_limits(image)
    value = (image, limits, window_keypoints(image, window[:2], sift_limits, most))
    _LAST.clear()
    if key is not None:
        _LAST.update(key=key, value=value)
    return value
