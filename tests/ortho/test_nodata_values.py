"""An integer orthoimage's nodata (0, the vendors' convention) marks only the pixels the model
does not see: a real 0 of the image is stored as 1, never as nodata (issue 53)."""

import json
import shutil

import numpy as np
import rasterio

from jaxgeo.cli import main
from jaxgeo.ortho._job import away_from_nodata


def test_valid_pixels_equal_to_nodata_move_one_step_away():
    values = np.array([[[0, 1, 7], [0, 65535, 0]]], dtype=np.uint16)
    valid = np.array([[True, True, True], [False, True, True]])
    out = away_from_nodata(values, valid, 0)
    assert out.tolist() == [[[1, 1, 7], [0, 65535, 1]]]  # the invalid 0 stays nodata
    top = away_from_nodata(values, valid, 65535)  # nodata at the type's maximum: one below
    assert top[0, 1, 1] == 65534 and top[0, 0, 0] == 0
    signed = away_from_nodata(np.array([[[-32768, 5]]], np.int16), np.ones((1, 2), bool), -32768)
    assert signed.tolist() == [[[-32767, 5]]]
    floats = np.array([[[0.0, np.nan]]])
    assert away_from_nodata(floats, np.ones((1, 2), bool), np.nan) is floats


def test_real_zero_pixels_of_a_uint16_crop_are_not_nodata(real_data, tmp_path, capsys):
    d = real_data / "ventoux"
    image = tmp_path / "left_image.tif"
    shutil.copy(d / "left_image.tif", image)
    with rasterio.open(image, "r+") as f:  # dark water: a block of real zeros mid-image
        data = f.read()
        data[:, 200:260, 200:260] = 0
        f.write(data)
    out = tmp_path / "ortho.tif"
    argv = ["ortho", str(image), "--model", str(real_data / "phr_ventoux__left_image.geom"),
            "--dem", str(d / "dem" / "N44E005_srtm90.tif"), "--geoid",
            str(d / "dem" / "egm96_15_crop_lon3-8_lat42-47.gtx"), "-o", str(out), "--quiet",
            "--json"]  # fmt: skip
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    with rasterio.open(out) as f:
        assert f.dtypes[0] == "uint16" and f.nodata == 0
        ortho = f.read(1)
    shown = int(np.count_nonzero(ortho != 0))
    # every pixel the model sees is a value, the block of zeros included (stored as 1)
    assert shown == round(report["valid_fraction"] * ortho.size)
    assert np.count_nonzero(ortho == 1) >= 0.8 * 60 * 60
