"""A DEM against the tie points' heights (issue 53): feet, a constant offset, another place are
named with the file; a DEM that holds the terrain, or too few ties, say nothing."""

import numpy as np

from jaxgeo.io._plausible import DEM_TIE_MEDIAN_M, dem_against_ties

RNG = np.random.default_rng(0)
TIES = RNG.uniform(80.0, 330.0, 200)  # the s2p triplet's terrain (m)


def test_a_dem_of_the_terrain_passes():
    dem = TIES + RNG.normal(0.0, 5.0, TIES.size) + 8.0  # roofs, trees, a few metres of bias
    assert dem_against_ties(TIES, dem, "dem.tif") is None
    assert dem_against_ties(TIES[:4], 3.28 * TIES[:4], "dem.tif") is None  # too few to say


def test_feet_are_named():
    why = dem_against_ties(TIES, TIES / 0.3048, "dem_ft.tif")
    assert why.startswith("dem_ft.tif: ") and "heights in feet" in why and "3.28x" in why


def test_metres_read_as_feet_are_named():
    assert "metres read as feet" in dem_against_ties(TIES, TIES * 0.3048, "dem.tif")


def test_a_constant_offset_is_named_with_its_size():
    why = dem_against_ties(TIES, TIES + 400.0 + RNG.normal(0.0, 3.0, TIES.size), "dem.tif")
    assert "a constant offset of +400 m" in why and "--geoid" in why
    assert f"median of +{400:d} m" in why


def test_another_place_and_nan_ties():
    dem = RNG.uniform(500.0, 1500.0, TIES.size)
    ties = TIES.copy()
    ties[:10] = np.nan  # ties without a height are left out
    why = dem_against_ties(ties, dem, "other.tif")
    assert "another place" in why and "190 ties" in why
    assert DEM_TIE_MEDIAN_M == 30.0
