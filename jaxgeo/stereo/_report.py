"""What a DSM run made: :class:`DSMReport` (:func:`~jaxgeo.stereo.make_dsm`,
:func:`~jaxgeo.stereo.tiled_dsm`), as JSON and for people."""

from __future__ import annotations

import dataclasses
import pathlib

from ..tiles import TilePlan, TileStats


@dataclasses.dataclass(frozen=True)
class DSMReport:
    """What :func:`make_dsm` (or :func:`tiled_dsm`) made: ``path`` (``None``: only the plan
    was written, at ``plan_path``), its grid (``epsg``, ``res_m``, ``width`` x ``height``
    cells), ``filled`` (share of cells with a height), ``interpolated`` (share of cells
    interpolated: of all the grid's, as ``filled``; :meth:`summary` prints it as a share of the
    cells with a height), the run (``tiles``, ``empty_tiles``: nodata, ``reused_tiles``,
    ``workers``, ``scheduler``, ``seconds``: of which ``plan_s`` planning, ``tiles_s`` running
    the tiles and ``mosaic_s`` writing the COG), per tile its :class:`~jaxgeo.tiles.TileStats`
    (``tile_stats``: a tile's pairs' numbers in ``details``, or why it is empty in
    ``no_data``); ``tiled``: made tile by tile (else one tile of the whole ROI, whose pairs'
    stats are ``pairs`` and median height sigma ``median_height_sigma_m``); the ``plan``."""

    path: pathlib.Path | None
    epsg: int
    res_m: float
    width: int
    height: int
    filled: float
    interpolated: float
    seconds: float
    tiles: int
    empty_tiles: int
    reused_tiles: int
    workers: int
    scheduler: str | None
    tile_stats: dict[str, TileStats]
    tiles_s: float = 0.0
    mosaic_s: float = 0.0
    plan_s: float = 0.0
    tiled: bool = True
    pairs: tuple[dict, ...] = ()
    median_height_sigma_m: float | None = None
    plan: TilePlan | None = None
    plan_path: pathlib.Path | None = None
    names: tuple[str, ...] = ()
    """The images' names (file stems), the reference first (for :meth:`as_dict`)."""
    height_sigma_covers: str = ""
    """What the ``height_sigma`` band covers (the band's ``covers`` tag): the matching, and the
    orientation's a priori or adjusted uncertainty."""

    def empty(self) -> dict[str, str]:
        """Why each tile without data has none (tile id -> reason)."""
        return {k: s.no_data for k, s in self.tile_stats.items() if s.no_data is not None}

    def as_dict(self) -> dict:
        """The report as JSON (what ``jaxgeo dsm --json`` prints): the DSM's grid, the share of
        cells filled and interpolated; untiled: the median height sigma and each pair's stats;
        tiled: the run (tiles, the empty ones' reasons, times, each tile's stats)."""
        out = {"output": str(self.path), "epsg": self.epsg, "res_m": self.res_m,
               "shape": [self.height, self.width], "filled": round(self.filled, 4),
               "interpolated": round(self.interpolated, 4),
               "height_sigma_covers": self.height_sigma_covers}  # fmt: skip
        if not self.tiled:
            ref = self.names[0] if self.names else ""
            pairs = [{"images": [ref, self.names[i + 1] if i + 1 < len(self.names) else ""],
                      **st} for i, st in enumerate(self.pairs)]  # fmt: skip
            return {**out, "median_height_sigma_m": self.median_height_sigma_m, "pairs": pairs}
        return {**out, "tiles": self.tiles, "empty_tiles": self.empty(),
                "reused_tiles": self.reused_tiles, "workers": self.workers,
                "scheduler": self.scheduler, "seconds": round(self.seconds, 1),
                "plan_s": round(self.plan_s, 1), "tiles_s": round(self.tiles_s, 1),
                "mosaic_s": round(self.mosaic_s, 1),
                "tile_stats": {k: s.as_dict() for k, s in self.tile_stats.items()}}  # fmt: skip

    def summary(self, out: str | None = None) -> str:
        """The report in a few lines for people (what ``jaxgeo dsm`` prints); ``out``: the
        output's name as the user gave it."""
        out = out or str(self.path)
        # ``interpolated`` is a share of the grid, as ``filled``: printed as one of the heights
        of_heights = self.interpolated / self.filled if self.filled > 0 else 0.0
        if not self.tiled:
            sigma = self.median_height_sigma_m
            lines = [f"wrote {out}: {self.width} x {self.height} cells of {self.res_m:g} m, "
                     f"EPSG:{self.epsg}, {100 * self.filled:.1f}% with a height (ellipsoidal, "
                     f"m), {100 * of_heights:.1f}% of them interpolated (band "
                     f"'filled'); median height_sigma {sigma or float('nan'):.2f} m"]  # fmt: skip
            for pair in self.as_dict()["pairs"]:
                lines.append(f"  {pair['images'][0]} - {pair['images'][1]}: " + _pair_line(pair))
            return "\n".join(lines + self._covers())
        empty = self.empty()
        where = (f"{self.workers} worker(s) at {self.scheduler}" if self.scheduler
                 else "this process")  # fmt: skip
        lines = [f"wrote {self.path}: {self.width} x {self.height} cells of {self.res_m:g} m, "
                 f"EPSG:{self.epsg}, {100 * self.filled:.1f}% with a height (ellipsoidal, m), "
                 f"{100 * of_heights:.1f}% of them interpolated (band 'filled'); {self.tiles} "
                 f"tiles ({len(empty)} without data, {self.reused_tiles} reused) on {where}; "
                 f"{self.seconds:.1f} s"]  # fmt: skip
        lines += [f"  tile {k}: no data ({why[:160]})" for k, why in list(empty.items())[:5]]
        return "\n".join(lines + self._covers())

    def _covers(self) -> list[str]:
        return [f"  height_sigma: {self.height_sigma_covers}"] if self.height_sigma_covers else []


def _pair_line(pair: dict) -> str:
    """One pair's numbers: ties, points dropped, vertical disparity, fill, height offset."""
    parts = [f"{pair.get('n_ties', '?')} ties"]
    if pair.get("n_points_outside_validity"):
        parts.append(f"{pair['n_points_outside_validity']} points outside the models' "
                     "validity cube dropped")  # fmt: skip
    if "vertical_disparity_px" in pair:
        parts.append(f"vertical disparity {pair['vertical_disparity_px']:+.2f} px removed")
    if "disparity_fill" in pair:
        parts.append(f"{100 * pair['disparity_fill']:.1f}% of pixels matched")
    if "height_offset_removed_m" in pair:
        parts.append(f"height offset {pair['height_offset_removed_m']:+.2f} m removed")
    return ", ".join(parts)
