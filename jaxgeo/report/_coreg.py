"""The report of a co-registration: DSM - REF before and after the alignment, as maps on one
symmetric colour scale and as histograms."""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ..io.internal import open_raster
from ._page import Page, new_figure
from ._raster import label_axes, read_quicklook


def _reference_on(look, ref) -> np.ndarray:
    """REF's heights on the cells of ``look`` (a DSM read decimated): a raster file's values as
    they are (bilinear), or a :class:`~jaxgeo.io.DEM`'s ellipsoidal heights (its geoid and
    offset applied), as :func:`jaxgeo.coreg.coregister` compares them."""
    from rasterio.crs import CRS
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    rows, cols = look.bands.shape[1:]
    if not isinstance(ref, (str, os.PathLike)):  # a DEM: heights at the cells' centres
        import pyproj

        x = look.transform.c + look.transform.a * (np.arange(cols) + 0.5)
        y = look.transform.f + look.transform.e * (np.arange(rows) + 0.5)
        xx, yy = np.meshgrid(x, y)
        to_lonlat = pyproj.Transformer.from_crs(look.crs_wkt, "EPSG:4326", always_xy=True)
        lon, lat = to_lonlat.transform(xx, yy)
        return np.asarray(ref.sample(np.stack([lon, lat], axis=-1)), dtype=np.float64)
    out = np.full((rows, cols), np.nan)
    with open_raster(ref) as r:
        reproject(r.read(1, masked=True).filled(np.nan).astype(np.float64), out,
                  src_transform=r.transform, src_crs=r.crs, src_nodata=np.nan,
                  dst_transform=look.transform, dst_crs=CRS.from_wkt(look.crs_wkt),
                  dst_nodata=np.nan, resampling=Resampling.bilinear)  # fmt: skip
    return out


def write_coregistration_report(
    result,
    dsm: str | os.PathLike,
    ref,
    path: str | os.PathLike,
    *,
    overwrite: bool = False,
) -> pathlib.Path:
    """Write the HTML report of the co-registration ``result`` (a
    :class:`jaxgeo.coreg.Coregistration` of :func:`jaxgeo.coreg.coregister` with ``output``,
    the aligned DSM, written) of the DSM file ``dsm`` onto ``ref`` (the reference raster, or
    the :class:`~jaxgeo.io.DEM` given to ``coregister``) to ``path``: the shift and the
    statistics of DSM - REF before and after (over the stable cells, and over every cell where
    a difference raster was written), the maps of DSM - REF before and after on one symmetric
    colour scale (m) and their histograms. The rasters are read decimated to a screen's size.
    Written atomically; an existing ``path`` only with ``overwrite``. Returns ``path``."""
    from matplotlib.ticker import MaxNLocator

    if result.output is None:
        raise ValueError("the co-registration report needs the aligned DSM (coregister(..., out=))")
    before_look = read_quicklook(dsm, (1,))
    after_look = read_quicklook(result.output, (1,))
    zref = _reference_on(before_look, ref)
    before = before_look.bands[0] - zref
    after = after_look.bands[0] - zref
    page = Page(f"Co-registration report: {pathlib.Path(dsm).name}",
                [f"DSM: {dsm}", f"reference: {getattr(ref, 'path', ref)}",
                 f"aligned DSM: {result.output}"])  # fmt: skip
    dx, dy, dz = result.shift_m
    page.section("Shift")
    page.table(("added to the DSM", "east (m)", "north (m)", "up (m)"), [("shift", dx, dy, dz)])
    state = "converged" if result.converged else "NOT converged"
    page.text(f"Nuth and Kääb: {result.iterations} iterations, {state}; {result.fit_cells} cells "
              f"in the last fit (estimated every {result.grid_step} cell(s)).",
              warn=not result.converged)  # fmt: skip
    page.section("DSM - REF before and after")
    header = ("statistic (m)", "before", "after")
    stats = [("the stable cells (the mask given, if any)", result.before.as_dict(),
              result.after.as_dict())]  # fmt: skip
    if result.diff is not None:
        stats.append(("every cell with heights in both", result.diff.before.as_dict(),
                      result.diff.after.as_dict()))  # fmt: skip
    for what, b, a in stats:
        page.text(f"Over {what}:")
        page.table(header, [(k, b[k], a[k]) for k in b if isinstance(b[k], int | float)])
    finite = np.concatenate([before[np.isfinite(before)], after[np.isfinite(after)]])
    lim = float(np.percentile(np.abs(finite), 98)) if finite.size else 1.0
    lim = max(lim, 1e-3)
    fig = new_figure(430)
    axes = fig.subplots(1, 2, sharex=True, sharey=True)
    for ax, dh, title in ((axes[0], before, "before"), (axes[1], after, "after")):
        im = ax.imshow(dh, cmap="RdBu_r", vmin=-lim, vmax=lim, extent=before_look.extent,
                       interpolation="nearest")  # fmt: skip
        med = np.nanmedian(dh) if np.isfinite(dh).any() else float("nan")
        ax.set_title(f"DSM - REF {title} (median {med:+.2f} m)")
        label_axes(ax, before_look)
        ax.xaxis.set_major_locator(MaxNLocator(3))
    axes[1].set_ylabel("")
    fig.colorbar(im, ax=axes, label="DSM - REF (m)", shrink=0.85, extend="both")
    page.figure(
        fig,
        f"DSM - REF before and after the alignment, one symmetric scale +-{lim:.3g} "
        "m (98th percentile of |DSM - REF|); red: the DSM above REF. A slope-correlated "
        "pattern before that is gone after is the horizontal shift removed.",
    )
    fig = new_figure(380)
    ax = fig.add_subplot()
    bins = np.linspace(-lim, lim, 81)
    for dh, label, colour in ((before, "before", "#d62728"), (after, "after", "#1f77b4")):
        values = dh[np.isfinite(dh)]
        ax.hist(
            np.clip(values, -lim, lim),
            bins=bins,
            histtype="step",
            lw=1.8,
            color=colour,
            label=f"{label}: median {np.median(values) if values.size else np.nan:+.2f} m",
        )
    ax.set_xlabel("DSM - REF (m)")
    ax.set_ylabel("cells")
    ax.legend(fontsize=10)
    ax.set_title("histogram of DSM - REF")
    page.figure(fig, "Histograms of DSM - REF before and after over the cells shown (values "
                "beyond the scale counted in the end bins).")  # fmt: skip
    return page.write(path, overwrite)
