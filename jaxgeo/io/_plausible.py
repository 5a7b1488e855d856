"""Is a DEM plausible for the images it is used with? Its heights against the tie points'.

A DEM's heights steer a job: the height range tie points are searched over, the tie heights of
an adjustment, where an ortho puts each pixel. A DEM in feet (x3.28), in another vertical
datum (orthometric heights taken as ellipsoidal: up to +-100 m) or of another place gives
heights that are wrong by tens to hundreds of metres, and nothing downstream can tell: the
search finds the few ties that happen to lie in the wrong range, the ortho moves. Tie points
triangulated from the images (their models' relative bias leaves metres, not tens of metres)
can tell: :func:`dem_against_ties` compares the DEM's heights at the ties with theirs and names
the likely cause. Without tie points (an ortho), :func:`dem_against_model` compares the DEM's
heights over the footprint with the model's validity range, which holds the terrain of a whole
scene.
"""

from __future__ import annotations

import numpy as np

FEET_PER_METRE = 1.0 / 0.3048
DEM_TIE_MEDIAN_M = 30.0
"""A DEM whose heights differ from the ties' by a median of more than this (m) is not the
terrain of these images (a DSM's roofs and trees over a bare-earth DEM, and the metres a
vendor's pointing leaves in the ties' heights, stay well below it on a median)."""
MIN_TIES = 5
"""Fewer ties than this say nothing about a DEM."""
VALIDITY_MARGIN_M = 100.0
"""Metres (at least; a tenth of the RPC's height scale if more) a DEM's median height may lie
beyond its model's validity range before :func:`dem_against_model` names it: a little
extrapolation is harmless (a coast at 0 m under a range from 40 m; a geoid left out)."""


def dem_against_ties(tie_h_m, dem_h_m, source: str) -> str | None:
    """Why the DEM ``source`` (a file name, for the message) does not hold the terrain of the
    tie points: its heights ``dem_h_m`` (m) at the ties differ from the ties' triangulated
    heights ``tie_h_m`` (m) by a median of more than :data:`DEM_TIE_MEDIAN_M`; the likely cause
    from the pattern (a factor 3.28: feet; a constant offset: a vertical datum or another
    place). ``None`` when they agree, or with fewer than :data:`MIN_TIES` ties with both."""
    tie = np.asarray(tie_h_m, float).reshape(-1)
    dem = np.asarray(dem_h_m, float).reshape(-1)
    ok = np.isfinite(tie) & np.isfinite(dem)
    if ok.sum() < MIN_TIES:
        return None
    tie, dem = tie[ok], dem[ok]
    dh = dem - tie
    if not np.median(np.abs(dh)) > DEM_TIE_MEDIAN_M:
        return None
    med = float(np.median(dh))
    nmad = 1.4826 * float(np.median(np.abs(dh - med)))
    cause = "a DEM of another place, or of heights in another unit or datum"
    away = np.abs(tie) > 1.0
    ratio = float(np.median(dem[away] / tie[away])) if away.sum() >= MIN_TIES else np.nan
    if abs(ratio - FEET_PER_METRE) < 0.1 * FEET_PER_METRE:
        cause = f"heights in feet (the DEM's are {ratio:.2f}x the ties'; metres expected)"
    elif abs(ratio - 1.0 / FEET_PER_METRE) < 0.1 / FEET_PER_METRE:
        cause = f"heights in metres read as feet (the DEM's are {ratio:.2f}x the ties')"
    elif nmad < 0.25 * abs(med):
        cause = (
            f"a constant offset of {med:+.0f} m: another vertical datum (orthometric heights "
            "taken as ellipsoidal: give --geoid; or a wrong --dem-offset-m), or a DEM of "
            "another place"
        )
    return (
        f"{source}: its heights differ from the tie points' triangulated heights at the same "
        f"places by a median of {med:+.0f} m ({int(ok.sum())} ties; tie heights "
        f"{np.percentile(tie, 5):.0f}..{np.percentile(tie, 95):.0f} m, the DEM's there "
        f"{np.percentile(dem, 5):.0f}..{np.percentile(dem, 95):.0f} m): likely {cause}; "
        "every height it gives (tie search range, ortho, DSM) is off by as much"
    )


def dem_against_model(dem_h_m, model, source: str, image: str) -> str | None:
    """Why the DEM ``source`` cannot hold the terrain of the image ``image`` whose model is
    ``model``: the median of its heights ``dem_h_m`` (m, ellipsoidal) over the image's
    footprint lies outside the model's validity range (its RPC's height offset +- scale: the
    vendor fits the RPC over the heights of the terrain it images) by more than
    :data:`VALIDITY_MARGIN_M` or a tenth of the scale, with the likely cause (a
    factor 3.28 against the height offset: feet; else an offset). ``None`` when it lies inside,
    for a model without an RPC, or without heights. The check needs no tie point (an ortho):
    it finds a DEM in feet or off by hundreds of metres over a whole scene, whose RPC's range
    is that of its terrain, but not over a small crop of it, whose terrain may lie anywhere in
    the range (the tie points' check, :func:`dem_against_ties`, does)."""
    rpc = model.base_rpc()
    h = np.asarray(dem_h_m, float).reshape(-1)
    h = h[np.isfinite(h)]
    if rpc is None or h.size == 0:
        return None
    # numpy: indexing the jax arrays would be two eager programs, compiled in every process
    off = float(np.asarray(rpc.ground_offset)[2])
    scale = abs(float(np.asarray(rpc.ground_scale)[2]))
    lo, hi = off - scale, off + scale
    med = float(np.median(h))
    margin = max(VALIDITY_MARGIN_M, 0.1 * scale)
    if lo - margin <= med <= hi + margin:
        return None
    ratio = med / off if abs(off) > 1.0 else np.nan
    if abs(ratio - FEET_PER_METRE) < 0.1 * FEET_PER_METRE:
        cause = f"heights in feet (their median is {ratio:.2f}x the model's height offset)"
    elif abs(ratio - 1.0 / FEET_PER_METRE) < 0.1 / FEET_PER_METRE:
        cause = f"heights in metres read as feet (their median is {ratio:.2f}x the offset)"
    else:
        side, by = ("above", med - hi) if med > hi else ("below", lo - med)
        cause = (
            f"heights {by:.0f} m or more {side} the range: another vertical datum or unit, a "
            "wrong --dem-offset-m, or a DEM of another place"
        )
    return (
        f"{source}: its heights over the footprint of {image} (median {med:.0f} m, "
        f"{np.percentile(h, 5):.0f}..{np.percentile(h, 95):.0f} m) lie outside the validity "
        f"range {lo:.0f}..{hi:.0f} m of the image's model (its RPC's height offset {off:.0f} "
        f"+- {scale:.0f} m, the heights of the terrain it was made for): likely {cause}; every "
        "height it gives would be off by as much"
    )
