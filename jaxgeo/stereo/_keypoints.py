"""The keypoints of a stereo pair's windows: SIFT at half resolution on the pixels already read,
and the reference window's kept for the next pair of the same tile (no work repeated across a
tile's pairs: the reference window, its stretch and its keypoints are the same for each)."""

from __future__ import annotations

import os

import numpy as np

from ._matching import sift_features, stretch_limits, to_uint8

SIFT_COARSE_MIN_PX, SIFT_LEVEL = 384, 2
"""A window this large (px, both sides) is searched for keypoints at 1 / ``SIFT_LEVEL``: at 192
coarse px a side it still holds thousands of keypoints (a 494 x 564 px edge window at full
resolution cost as much as a 1 Mpx one at half)."""

_LAST: dict = {}
"""The last reference window read (``key``, ``value``): one per process."""


def sift_level(shape) -> int:
    """The resolution level (1: full, :data:`SIFT_LEVEL`: half) of a window of ``shape`` (rows,
    cols, or (w, h): both sides count) searched for keypoints."""
    return SIFT_LEVEL if min(shape) >= SIFT_COARSE_MIN_PX else 1


def window_keypoints(image, origin, limits, most=None, level=None):
    """SIFT keypoints (raster px) and descriptors of a window read (``image``, its first pixel
    at ``origin``; ``limits``: its uint8 stretch), at half resolution from
    :data:`SIFT_COARSE_MIN_PX` (what the ties fix needs no finer keypoint; a quarter of the
    cost; ``level``: that of another window, the pair's reference, instead of this one's size);
    about ``most``, spread (:func:`~._matching.sift_features`; ``None``: all)."""
    import cv2

    image8 = to_uint8(image, limits)
    level = sift_level(image8.shape) if level is None else int(level)
    if level > 1:  # whole blocks: a size not a multiple of the level would stretch the scale
        h, w = (n - n % level for n in image8.shape)
        image8 = cv2.resize(image8[:h, :w], (w // level, h // level), interpolation=cv2.INTER_AREA)
    xy, desc = sift_features(image8, most=most)  # a coarse pixel's centre: its block's
    return (xy + 0.5) * level - 0.5 + np.asarray(origin, dtype=float), desc


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
    coarse = sift_level(image.shape) > 1
    sift_limits = limits if coarse else stretch_limits(image)
    value = (image, limits, window_keypoints(image, window[:2], sift_limits, most))
    _LAST.clear()
    if key is not None:
        _LAST.update(key=key, value=value)
    return value
