"""Resampling of an image window at fractional positions (numpy, host side).

Positions are jaxgeo image coordinates relative to the window: ``(x, y) = (col, row)``, integer
at pixel centres. ``nearest``, ``bilinear`` and ``cubic`` (Keys cubic convolution, a = -0.5, as
GDAL's ``cubic``) hold the edge pixel beyond the last pixel centre. A position outside the
window's pixel area ``[-0.5, n - 0.5]`` is invalid.
"""

from __future__ import annotations

import numpy as np

RESAMPLINGS = ("nearest", "bilinear", "cubic")


def _keys(t: np.ndarray) -> list[np.ndarray]:
    """Cubic convolution weights (a = -0.5) of the 4 taps at offsets -1, 0, 1, 2."""
    a = -0.5

    def w(d):
        d = np.abs(d)
        return np.where(
            d <= 1, ((a + 2) * d - (a + 3)) * d * d + 1,
            np.where(d < 2, ((a * d - 5 * a) * d + 8 * a) * d - 4 * a, 0.0),
        )  # fmt: skip

    return [w(t + 1), w(t), w(1 - t), w(2 - t)]


def sample_window(
    window: np.ndarray, x: np.ndarray, y: np.ndarray, method: str
) -> tuple[np.ndarray, np.ndarray]:
    """Sample ``window`` ``(bands, rows, cols)`` at ``(x, y)`` -> ``(bands, *x.shape)`` float64.

    Returns the values and a boolean ``valid`` mask (finite position inside the window).
    """
    if method not in RESAMPLINGS:
        raise ValueError(f"unknown resampling {method!r}; expected one of {RESAMPLINGS}")
    bands, rows, cols = window.shape
    with np.errstate(invalid="ignore"):
        valid = (x >= -0.5) & (x <= cols - 0.5) & (y >= -0.5) & (y <= rows - 0.5)
    xs = np.where(valid, x, 0.0)
    ys = np.where(valid, y, 0.0)
    src = window.reshape(bands, -1)
    out = np.zeros((bands, *x.shape))
    if method == "nearest":
        c = np.clip(np.floor(xs + 0.5).astype(np.int64), 0, cols - 1)
        r = np.clip(np.floor(ys + 0.5).astype(np.int64), 0, rows - 1)
        out = src[:, r * cols + c].astype(float)
    elif method == "bilinear":
        c0 = np.floor(xs).astype(np.int64)
        r0 = np.floor(ys).astype(np.int64)
        tc, tr = xs - c0, ys - r0
        for dr, wr in ((0, 1 - tr), (1, tr)):
            rr = np.clip(r0 + dr, 0, rows - 1) * cols
            for dc, wc in ((0, 1 - tc), (1, tc)):
                cc = np.clip(c0 + dc, 0, cols - 1)
                out += (wr * wc) * src[:, rr + cc]
    else:
        c0 = np.floor(xs).astype(np.int64)
        r0 = np.floor(ys).astype(np.int64)
        wcs = _keys(xs - c0)
        wrs = _keys(ys - r0)
        for dr in range(4):
            rr = np.clip(r0 + dr - 1, 0, rows - 1) * cols
            for dc in range(4):
                cc = np.clip(c0 + dc - 1, 0, cols - 1)
                out += (wrs[dr] * wcs[dc]) * src[:, rr + cc]
    return out, valid
