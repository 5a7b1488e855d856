"""``jaxgeo ortho`` bad input: clear errors, nothing written."""

import numpy as np
import rasterio

import jaxgeo
from jaxgeo.cli import main
from tests.conftest import PLEIADES_TIF
from tests.ortho.conftest import nice_dem_synthetic, write_dem  # noqa: F401  (fixture)


def test_image_without_any_model(tmp_path, nice_dem_synthetic, capsys):  # noqa: F811
    plain = tmp_path / "plain.tif"
    with rasterio.open(plain, "w", driver="GTiff", width=8, height=8, count=1,
                       dtype="uint8") as dst:  # fmt: skip
        dst.write(np.zeros((1, 8, 8), dtype="uint8"))
    out = tmp_path / "out.tif"
    assert main(["ortho", str(plain), "--dem", str(nice_dem_synthetic), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "plain.tif" in err and "no sensor model found" in err and "--model" in err
    assert not out.exists()


def test_dem_not_covering_the_footprint(tmp_path, real_data, capsys):
    rpc = jaxgeo.read_rpc(real_data / PLEIADES_TIF)
    lon, lat = (float(v) for v in rpc.localize(np.array([0.0, 0.0]), 0.0)[:2])
    step = 1e-4  # a 20 x 20 m DEM at the image's first corner: a sliver of its footprint
    dem = write_dem(tmp_path / "small.tif", np.zeros((2, 2)), lon - step, lat + step, step)
    out = tmp_path / "out.tif"
    args = ["ortho", str(real_data / PLEIADES_TIF), "--dem", str(dem), "-o", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "small.tif" in err and "covers only" in err and "% of the footprint" in err
    assert not out.exists()
