"""Checks of an orthoimage's options (one-line OrthoErrors naming the option), the footprint on
the DEM (points of each line of sight on the DEM: they project back onto the image's border and
their height is the DEM's), and the plan's tiles."""

import math

import numpy as np
import pyproj
import pytest

import jaxgeo
from jaxgeo.io import read_dem
from jaxgeo.ortho import OrthoError, OrthoSettings, plan_ortho
from jaxgeo.ortho._grid import border_pixels, on_dem
from jaxgeo.ortho._validate import (
    check_bounds,
    check_bounds_cover,
    check_crs,
    check_res,
    check_size,
    clip_polygon,
    polygon_area,
)
from tests.ortho.conftest import VENTOUX_ORIGIN, ventoux_dem_ellipsoidal  # noqa: F401


def test_crs():
    assert check_crs("EPSG:32631").to_epsg() == 32631
    assert check_crs(4326).is_geographic
    with pytest.raises(OrthoError, match="invalid CRS 'EPSG:99999'") as err:
        check_crs("EPSG:99999")
    assert "\n" not in str(err.value) and isinstance(err.value, ValueError)
    with pytest.raises(OrthoError, match="not a map CRS"):
        check_crs("EPSG:4978")  # geocentric


def test_resolution():
    utm, geo = check_crs("EPSG:32631"), check_crs("EPSG:4326")
    assert check_res(0.5, utm, 0.5) == 0.5 and check_res(4.5e-6, geo, 0.5) == 4.5e-6
    for bad in (0, -1, float("nan"), float("inf"), "x"):
        with pytest.raises(OrthoError, match="resolution"):
            check_res(bad, utm, 0.5)
    with pytest.raises(OrthoError, match="degrees given as metres") as err:
        check_res(0.5, geo, 0.5)
    assert "55.7 km a pixel" in str(err.value)
    assert check_res(0.01, geo, 500.0) == 0.01  # a 500 m GSD: 0.01 degree is plausible


def test_bounds_and_footprint_cover():
    assert check_bounds([0, 1, 2, 3]) == (0.0, 1.0, 2.0, 3.0)
    for bad in ([2, 0, 1, 1], [0, 0, 1], [0, 0, np.nan, 1], "abcd"):
        with pytest.raises(OrthoError):
            check_bounds(bad)
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], dtype=float)
    assert polygon_area(clip_polygon(square, (5, 5, 20, 20))) == pytest.approx(25.0)
    assert polygon_area(clip_polygon(square, (20, 20, 30, 30))) == 0.0
    assert check_bounds_cover((5, 5, 15, 15), square, "img") == pytest.approx(0.25)
    with pytest.raises(OrthoError, match="outside the footprint of img.*no data"):
        check_bounds_cover((20, 20, 30, 30), square, "img")


def test_size():
    check_size(100, 100, 0.5, 2e9, 0.5)
    check_size(10**5, 10**5, 0.5, 0, 0.5)  # 0: no limit
    with pytest.raises(OrthoError, match="1 x 1 px at resolution 1e\\+06"):
        check_size(1, 1, 1e6, 2e9, 0.5)
    with pytest.raises(OrthoError, match="over the limit of 1e\\+06 px"):
        check_size(2000, 1000, 0.5, 1e6, 0.5)


def test_settings_are_checked_when_made_and_name_the_field():
    s = OrthoSettings(crs=32631, res_m=2, bounds=[0, 1, 2, 3])
    assert s.res_m == 2.0 and s.bounds == (0.0, 1.0, 2.0, 3.0)  # as checked: floats, a tuple
    assert hash(s) == hash(OrthoSettings(crs=32631, res_m=2.0, bounds=(0, 1, 2, 3)))
    bad = {
        "resampling": ({"resampling": "lanczos"}, "unknown resampling 'lanczos'"),
        "occlusion": ({"occlusion": "yes"}, "unknown occlusion mode 'yes'"),
        "compress": ({"compress": "jpeg"}, "unknown compression 'jpeg'"),
        "step odd": ({"step_px": 15}, "step_px must be an even number >= 2"),
        "tile": ({"tile_px": 32}, "tile_px must be >= 64"),
        "tol": ({"tol_px": -0.1}, "tol_px must be a finite number >= 0"),
        "tol nan": ({"tol_px": float("nan")}, "tol_px must be a finite number >= 0"),
        "limit": ({"max_pixels": -1}, "max_pixels must be >= 0"),
        "crs": ({"crs": "EPSG:99999"}, "invalid CRS 'EPSG:99999'"),
        "res": ({"res_m": 0}, "resolution must be > 0"),
        "bounds": ({"crs": 32631, "bounds": (2, 0, 1, 1)}, "are empty"),
        "bounds without a CRS": ({"bounds": (0, 0, 1, 1)}, "bounds need the output CRS"),
    }
    for kwargs, message in bad.values():
        with pytest.raises(OrthoError, match=message):
            OrthoSettings(**kwargs)
    assert OrthoSettings(max_pixels=None, nodata=float("nan"), tol_px=0).max_pixels is None


def test_plan_and_ortho_take_settings_objects_only(tmp_path):
    from jaxgeo.ortho import orthorectify

    with pytest.raises(TypeError, match="settings"):
        plan_ortho("i.tif", "dem.tif", tmp_path / "o.tif", {"crs": "EPSG:32631"})
    with pytest.raises(TypeError, match="tiles"):
        orthorectify("i.tif", "dem.tif", tmp_path / "o.tif", OrthoSettings(), {"workers": 0})
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def ventoux(real_data, ventoux_dem_ellipsoidal):  # noqa: F811
    from jaxgeo.models import Biased, ShiftBias

    rpc = jaxgeo.read_rpc(real_data / "phr_ventoux__left_image.geom")
    model = Biased(rpc, ShiftBias(np.array(VENTOUX_ORIGIN)))
    dem = read_dem(ventoux_dem_ellipsoidal, height="ellipsoidal")
    return model, dem, rpc


def test_footprint_points_lie_on_the_dem(ventoux):
    model, dem, _ = ventoux
    lon, lat = (float(v) for v in model.localize(np.array([250.0, 250.0]), 1000.0)[:2])
    grid = dem.grid((lon - 0.03, lat - 0.03, lon + 0.03, lat + 0.03))
    xy = border_pixels(500, 500)
    g, ok = on_dem(model, xy, grid)
    assert ok.all()
    assert np.abs(np.asarray(grid.height(g[:, :2])) - g[:, 2]).max() < 0.01
    assert np.abs(np.asarray(model.project(g)) - xy).max() < 1e-6


def test_plan_refuses_before_computing_and_tiles_follow_the_resolution(ventoux, real_data,
                                                                        tmp_path):  # fmt: skip
    _, dem, rpc = ventoux  # the crop's frame: its pixel-space geotransform
    image = real_data / "ventoux" / "left_image.tif"
    with pytest.raises(OrthoError, match="is an input"):
        plan_ortho(image, dem, image, model=rpc, overwrite=True)
    with pytest.raises(OrthoError, match="bounds need the output CRS"):
        plan_ortho(image, dem, tmp_path / "o.tif", OrthoSettings(bounds=(0, 0, 1, 1)), model=rpc)
    # a resolution 8 x coarser than the GSD: smaller tiles (a power of two), bounded windows
    fine = plan_ortho(image, dem, tmp_path / "o.tif", OrthoSettings(tile_px=256), model=rpc)
    res = fine.job.spec.transform[0]
    coarse = plan_ortho(image, dem, tmp_path / "o.tif", OrthoSettings(res_m=8 * res, tile_px=1024),
                        model=rpc)  # fmt: skip
    assert math.log2(coarse.plan.tile_px).is_integer() and coarse.plan.tile_px < 1024
    windows = [t.inputs["image_window"] for t in coarse.plan.tiles if t.inputs["image_window"]]
    assert max(max(w[2], w[3]) for w in windows) <= 2048 + 64
    crs = pyproj.CRS.from_user_input(fine.crs)
    assert crs.to_epsg() == 32631 and fine.plan.width * fine.plan.height > 0.2e6
