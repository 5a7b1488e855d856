"""A DEM that is not the terrain of the images (issue 53): in feet, or hundreds of metres off,
it would choose the tie search range and the ties would be the few that happen to lie in it;
the ties' own heights disagree with it and the warning names the file and the likely cause.
On the s2p Pleiades triplet (img_02 - img_01) with s2p's expected DSM as the DEM."""

import warnings

import numpy as np
import pytest
import rasterio

from jaxgeo.io import open_image, read_dem
from jaxgeo.stereo import MatchSettings, TieWarning, tie_points

ROI = (250, 250, 500, 500)  # inside the DSM's extent


@pytest.fixture(scope="module")
def dems(shared_data, tmp_path_factory):
    from scipy import ndimage

    folder = tmp_path_factory.mktemp("dems")
    with rasterio.open(shared_data / "s2p_triplet" / "expected_dsm.tif") as f:
        z, profile = f.read(1), f.profile
    idx = ndimage.distance_transform_edt(~np.isfinite(z), return_distances=False,
                                         return_indices=True)  # fmt: skip
    z = z[tuple(idx)]  # voids filled with their nearest height
    out = {}
    for name, scale, offset in (("m", 1.0, 0.0), ("ft", 1.0 / 0.3048, 0.0), ("off", 1.0, 500.0)):
        out[name] = folder / f"dem_{name}.tif"
        with rasterio.open(out[name], "w", **profile) as g:
            g.write((z * scale + offset).astype(profile["dtype"]), 1)
    return out


def _ties(shared_data, dem_path):
    d = shared_data / "s2p_triplet"
    a, b = open_image(d / "img_02.tif"), open_image(d / "img_01.tif")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ties = tie_points(a.model, b.model, a.path, b.path, MatchSettings(roi=ROI),
                          dem=read_dem(dem_path))  # fmt: skip
    return ties, [str(w.message) for w in caught if issubclass(w.category, TieWarning)]


def test_dem_in_metres_passes(shared_data, dems):
    ties, warned = _ties(shared_data, dems["m"])
    assert len(ties) > 1000 and warned == []


def test_dem_in_feet_is_named(shared_data, dems):
    ties, warned = _ties(shared_data, dems["ft"])
    assert len(warned) == 1, warned
    assert str(dems["ft"]) in warned[0] and "heights in feet" in warned[0]
    assert "far fewer than the images support" in warned[0]


def test_dem_500_m_off_is_named(shared_data, dems):
    _, warned = _ties(shared_data, dems["off"])
    assert len(warned) == 1 and str(dems["off"]) in warned[0], warned
    assert "its heights differ from the tie points'" in warned[0]


def test_dsm_command_names_the_dem(shared_data, dems, tmp_path, capsys):
    """``jaxgeo dsm --dem`` with the DEM in feet: refused before any tile (exit 2, nothing
    written), the error naming the file (the tie points of one window against it)."""
    from jaxgeo.cli import main

    d = shared_data / "s2p_triplet"
    out = tmp_path / "dsm.tif"
    rc = main(["dsm", str(d / "img_02.tif"), str(d / "img_01.tif"), "--roi", "350", "350",
               "200", "200", "--dem", str(dems["ft"]), "-o", str(out), "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert "Traceback" not in err and "TieWarning" not in err
    assert f"jaxgeo dsm: error: {dems['ft']}: its heights differ" in err and "feet" in err
    assert rc == 2 and not out.exists()
