"""The report of an ortho image: a quicklook on its grid, with the extent in its CRS's units."""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ._page import Page, new_figure
from ._raster import label_axes, percentile_stretch, read_quicklook


def write_ortho_report(
    ortho: str | os.PathLike,
    path: str | os.PathLike,
    result=None,
    *,
    overwrite: bool = False,
) -> pathlib.Path:
    """Write the HTML report of the ortho image ``ortho`` to ``path``: a quicklook (read
    decimated to a screen's size; its first three bands as red, green, blue, else its first
    band in grey; each stretched between its 2nd and 98th percentiles) on the output grid, its
    axes in the CRS's units, and a table of the grid (``result``, the
    :class:`jaxgeo.ortho.OrthoReport` that made it, adds its figures). Written atomically; an
    existing ``path`` only with ``overwrite``. Returns ``path``."""
    look = read_quicklook(ortho)
    bands = look.bands[:3] if look.bands.shape[0] >= 3 else look.bands[:1]
    valid = np.all(np.isfinite(bands), axis=0)
    page = Page(f"Ortho report: {pathlib.Path(ortho).name}", [f"ortho image: {ortho}"])
    rows = [("size", f"{look.bands.shape[2] * look.step:.0f} x "
                     f"{look.bands.shape[1] * look.step:.0f} px, {look.bands.shape[0]} band(s)"),
            ("CRS", look.crs or "none"),
            ("pixel size", f"{abs(look.transform.a) / look.step:.4g} {look.units}"),
            ("extent (left, right, bottom, top)", ", ".join(f"{v:.10g}" for v in look.extent)),
            ("shown every", f"{look.step:.3g} px"),
            ("pixels with data (shown)", f"{100 * valid.mean():.1f} %")]  # fmt: skip
    if result is not None:
        rows += [("grid error left", f"{result.grid_error_px:.2g} px"),
                 ("run time", f"{result.seconds:.1f} s")]  # fmt: skip
        if getattr(result, "occluded_fraction", None) is not None:
            rows.append(("occluded", f"{100 * result.occluded_fraction:.2f} %"))
    page.section("Summary")
    page.table(("", "value"), rows)
    page.section("Quicklook")
    shown = np.empty(bands.shape[1:] + (4,))
    for k in range(3):
        b = bands[min(k, bands.shape[0] - 1)]
        lo, hi = percentile_stretch(b)
        shown[..., k] = np.clip((b - lo) / (hi - lo), 0.0, 1.0)
    shown[..., 3] = valid  # no data: transparent (the page's white)
    shown[~valid, :3] = 1.0
    height_px = int(np.clip(900 * bands.shape[1] / max(bands.shape[2], 1), 300, 900))
    fig = new_figure(height_px)
    ax = fig.add_subplot()
    ax.imshow(shown, extent=look.extent, interpolation="nearest")
    label_axes(ax, look)
    ax.set_title(f"{pathlib.Path(ortho).name} ({look.crs or 'no CRS'})")
    what = "bands 1-3 as RGB" if bands.shape[0] == 3 else "band 1"
    page.figure(fig, f"Quicklook ({what}, 2-98 % stretch per band; white: no data), every "
                f"{look.step:.3g} px, on the output grid.")  # fmt: skip
    return page.write(path, overwrite)
