"""``jaxgeo.stereo.DSMSettings``: frozen, checked when made, each error naming its field (which
``jaxgeo dsm`` turns into its option's name)."""

import dataclasses

import pytest

from jaxgeo.cli._dsm import _named
from jaxgeo.stereo import DSMSettings, DSMSettingsError, SGMSettings


@pytest.mark.parametrize(
    "field, value, option, message",
    [
        ("res_m", 0.0, "--res", "--res 0: expected a positive cell size in metres"),
        ("res_m", float("nan"), "--res", "--res nan: expected a positive cell size"),
        ("band_rows", 0, "--band-rows", "--band-rows 0: expected a positive number of rows"),
        ("max_hole_m", -1.0, "--max-hole", "--max-hole -1: expected metres >= 0"),
        ("heights", (10.0, 5.0), "--heights", "--heights 10 5: need finite HMIN < HMAX"),
        ("tile_px", 32, "--tile", "--tile must be >= 64, got 32"),
        ("roi", (-1, 0, 10, 10), "--roi", "--roi -1 0 10 10: need col, row >= 0"),
        ("triangulation", "nearest", "--triangulation", "--triangulation 'nearest'"),
        ("epi_step", 0, None, "epi_step 0: expected >= 1 px"),
        ("epipolar_tol_px", 0.0, None, "epipolar_tol_px 0: must be > 0"),
    ],
)
def test_a_bad_value_names_its_field(field, value, option, message):
    with pytest.raises(DSMSettingsError) as err:
        DSMSettings(**{field: value})
    assert err.value.field == field and isinstance(err.value, ValueError)
    assert str(err.value).startswith(field)
    assert _named(err.value).startswith(message)


def test_frozen_hashable_and_normalised():
    s = DSMSettings(roi=(1, 2, 30, 40), heights=(10, 200), epsg=32631)
    assert s.roi == (1, 2, 30, 40) and s.heights == (10.0, 200.0)
    assert isinstance(s.heights[0], float)
    assert hash(s) == hash(DSMSettings(roi=(1, 2, 30, 40), heights=(10.0, 200.0), epsg=32631))
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.res_m = 1.0
    assert DSMSettings(sgm=SGMSettings(block_size=7)).sgm.block_size == 7
    with pytest.raises(DSMSettingsError, match="^res_m"):
        dataclasses.replace(s, res_m=-1.0)
