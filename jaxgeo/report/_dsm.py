"""The report of a DSM: its relief (hillshade), where it has heights (measured, interpolated,
none) and the height_sigma map, with the figures a user judges a DSM by first."""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ._page import Page, new_figure
from ._raster import band_index, hillshade, label_axes, percentile_stretch, read_quicklook


def write_dsm_report(
    dsm: str | os.PathLike,
    path: str | os.PathLike,
    result=None,
    *,
    overwrite: bool = False,
) -> pathlib.Path:
    """Write the HTML report of the jaxgeo DSM ``dsm`` (a GeoTIFF with the bands ``height``,
    ``count``, ``filled``, ``height_sigma`` of :data:`jaxgeo.stereo.DSM_BANDS`; a DEM of one
    band gets its hillshade only) to ``path``: a hillshade of the heights (coloured by height,
    m), the cells measured / interpolated / without a height, and the ``height_sigma`` map (m),
    each with its colour bar; ``result`` (the :class:`jaxgeo.stereo.DSMReport` that made it,
    optional) adds its figures to the table. The raster is read decimated to a screen's size
    (a whole scene is never read). Written atomically; an existing ``path`` only with
    ``overwrite``. Returns ``path``."""
    look = read_quicklook(dsm)
    h_i = band_index(look, "height")
    z = look.bands[0 if h_i is None else h_i]
    page = Page(f"DSM report: {pathlib.Path(dsm).name}", [f"DSM: {dsm}"])
    cell = abs(look.transform.a)
    rows = [("grid", f"{look.bands.shape[2] * look.step:.0f} x "
                     f"{look.bands.shape[1] * look.step:.0f} cells"),
            ("CRS", look.crs or "none"), ("cell size", f"{cell / look.step:.4g} {look.units}"),
            ("shown every", f"{look.step:.3g} cells")]  # fmt: skip
    finite = np.isfinite(z)
    rows.append(("cells with a height", f"{100 * finite.mean():.1f} %"))
    if finite.any():
        rows.append(("height range (m)", f"{np.nanmin(z):.1f} .. {np.nanmax(z):.1f}"))
    if result is not None:
        rows += [("filled (report)", f"{100 * result.filled:.1f} %"),
                 ("interpolated (report)", f"{100 * result.interpolated:.1f} %"),
                 ("tiles", f"{result.tiles} ({result.empty_tiles} without data)"),
                 ("run time", f"{result.seconds:.1f} s")]  # fmt: skip
        if result.median_height_sigma_m is not None:
            rows.append(("median height_sigma", f"{result.median_height_sigma_m:.3g} m"))
    page.section("Summary")
    page.table(("", "value"), rows)

    page.section("Relief")
    fig = new_figure(620)
    ax = fig.add_subplot()
    metric = look.units not in ("", "degrees")
    shade = hillshade(z, cell if metric else cell * 111_000.0)
    ax.imshow(shade, cmap="gray", vmin=0, vmax=1, extent=look.extent, interpolation="nearest")
    lo, hi = percentile_stretch(z, 1, 99)
    im = ax.imshow(z, cmap="terrain", vmin=lo, vmax=hi, alpha=0.45, extent=look.extent,
                   interpolation="nearest")  # fmt: skip
    fig.colorbar(im, ax=ax, label="height above the WGS84 ellipsoid (m)", shrink=0.85)
    ax.set_title("hillshade (lit from the north-west, 45°), coloured by height")
    label_axes(ax, look)
    page.figure(fig, "The DSM's relief: a hillshade of its height band, coloured by height "
                "(m, 1st-99th percentile); white: no height.")  # fmt: skip

    f_i, c_i = band_index(look, "filled"), band_index(look, "count")
    if f_i is not None or c_i is not None:
        page.section("Where the heights come from")
        _mask_figure(page, look, z, f_i, c_i)
    s_i = band_index(look, "height_sigma")
    if s_i is not None:
        page.section("Height uncertainty")
        sigma = look.bands[s_i]
        fig = new_figure(620)
        ax = fig.add_subplot()
        lo, hi = percentile_stretch(sigma, 2, 98)
        im = ax.imshow(sigma, cmap="viridis", vmin=lo, vmax=hi, extent=look.extent,
                       interpolation="nearest")  # fmt: skip
        fig.colorbar(im, ax=ax, label="height_sigma (m)", shrink=0.85, extend="both")
        ax.set_title("height_sigma: standard deviation of each cell's height")
        label_axes(ax, look)
        med = np.nanmedian(sigma) if np.isfinite(sigma).any() else float("nan")
        page.figure(
            fig,
            f"height_sigma (m; colour scale from the 2nd to the 98th percentile, median "
            f"{med:.3g} m): the matching's and the orientation's uncertainty per cell.",
        )
    return page.write(path, overwrite)


def _mask_figure(page: Page, look, z, f_i, c_i) -> None:
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    classes = np.where(np.isfinite(z), 1, 0).astype(float)  # 0 none, 1 measured, 2 filled
    if f_i is not None:
        classes[np.isfinite(z) & (look.bands[f_i] > 0.5)] = 2
    elif c_i is not None:
        classes[np.isfinite(z) & (look.bands[c_i] == 0)] = 2
    colours = ("#f2b8b5", "#bdbdbd", "#1f77b4")
    fig = new_figure(620)
    ax = fig.add_subplot()
    ax.imshow(classes, cmap=ListedColormap(colours), vmin=-0.5, vmax=2.5, extent=look.extent,
              interpolation="nearest")  # fmt: skip
    shares = [100 * np.mean(classes == k) for k in range(3)]
    labels = ("no height", "measured", "interpolated (filled band)")
    ax.legend(handles=[Patch(color=c, label=f"{t}: {s:.1f} %")
                       for c, t, s in zip(colours, labels, shares, strict=True)],
              loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=10)  # fmt: skip
    ax.set_title("valid and filled cells")
    label_axes(ax, look)
    page.figure(fig, "Measured cells (grey), cells interpolated from the rim of a small hole "
                "(blue) and cells without a height (pink: outside the images' overlap, or not "
                "matched), as shares of the grid.")  # fmt: skip
