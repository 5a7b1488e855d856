"""Is a DEM plausible for the images it is used with? Its heights against the tie points'.

A DEM's heights steer a job: the height range tie points are searched over, the tie heights of
an adjustment, where an ortho puts each pixel. A DEM in feet (x3.28), in another vertical
datum (orthometric heights taken as ellipsoidal: up to +-100 m) or of another place gives
heights that are wrong by tens to hundreds of metres, and nothing downstream can tell: the
search finds the few ties that happen to lie in the wrong range, the ortho moves. Tie points
triangulated from the images (their models' relative bias leaves metres, not tens of metres)
can tell: :func:`dem_against_ties` compares the DEM's heights at the ties with theirs and names
the likely cause.
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
