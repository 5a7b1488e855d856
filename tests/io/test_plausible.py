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


def _rpc(height_off, height_scale):
    from jaxgeo.models import RPC

    num = np.zeros((2, 20))
    num[:, 1], num[1, 2] = 1.0, 1.0
    den = np.zeros((2, 20))
    den[:, 0] = 1.0
    return RPC(num, den, [5.0, 44.0, height_off], [0.1, 0.1, height_scale], [500.0, 500.0],
               [500.0, 500.0])  # fmt: skip


def test_a_dem_against_the_models_validity_range():
    """Without ties (an ortho): a DEM whose heights over the footprint lie outside the model's
    validity range (height offset +- scale) is named, with feet or the distance as cause."""
    from jaxgeo.io._plausible import dem_against_model

    model = _rpc(1075.0, 885.0)  # the Ventoux Pleiades product: 190..1960 m
    terrain = RNG.uniform(900.0, 1300.0, 500)  # a whole scene's terrain about its offset
    assert dem_against_model(terrain, model, "dem.tif", "img.tif") is None
    assert dem_against_model(terrain + 500.0, model, "dem.tif", "img.tif") is None  # inside
    why = dem_against_model(terrain / 0.3048, model, "dem_ft.tif", "img.tif")
    assert why.startswith("dem_ft.tif: ") and "footprint of img.tif" in why
    assert "heights in feet" in why and "190..1960 m" in why
    why = dem_against_model(terrain + 1500.0, model, "dem.tif", "img.tif")
    assert "above the range" in why and "feet" not in why
    assert "below the range" in dem_against_model(terrain - 1500.0, model, "d.tif", "i.tif")
    # a little beyond the range (a coast at 0 m under a range from 190 m): extrapolated, fine
    assert dem_against_model(np.full(9, 100.0), model, "d.tif", "i.tif") is None
    assert dem_against_model(np.full(9, 60.0), model, "d.tif", "i.tif") is not None
    assert dem_against_model(np.full(3, np.nan), model, "d.tif", "i.tif") is None
    # a crop of a scene: its terrain may lie anywhere in the range; feet inside it pass (the
    # tie points' check finds them where there are ties)
    assert dem_against_model(np.full(9, 500.0) / 0.3048, model, "d.tif", "i.tif") is None


def test_a_dem_declaring_feet_is_refused(tmp_path):
    import pytest
    import rasterio
    from rasterio.transform import Affine

    from jaxgeo.io import read_dem

    profile = dict(driver="GTiff", width=8, height=8, count=1, dtype="float32",
                   crs="EPSG:4326", transform=Affine(0.01, 0.0, 5.0, 0.0, -0.01, 45.0))  # fmt: skip
    for name, units, crs in (("band_ft.tif", ("ft",), "EPSG:4326"),
                             ("navd88_ftus.tif", None, "EPSG:4326+6360"),
                             ("metres.tif", ("m",), "EPSG:4326")):  # fmt: skip
        with rasterio.open(tmp_path / name, "w", **(profile | {"crs": crs})) as dst:
            dst.write(np.full((1, 8, 8), 300.0, "float32"))
            if units:
                dst.units = units
    with pytest.raises(ValueError, match=r"band_ft.tif: declares the heights of band 1 in 'ft'"):
        read_dem(tmp_path / "band_ft.tif")
    with pytest.raises(ValueError, match=r"navd88_ftus.tif: .* in 'US survey foot'.*0.3048"):
        read_dem(tmp_path / "navd88_ftus.tif")
    assert read_dem(tmp_path / "metres.tif").path.name == "metres.tif"
