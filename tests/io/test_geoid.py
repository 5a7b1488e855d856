"""Geoids offline: the EGM96 grid jaxgeo ships (NGA's WW15MGH.DAC) against PROJ's, used when
PROJ's grid is not installed; PROJ's grid first when it is; EGM2008's error says where to get it."""

import pathlib
import shutil

import numpy as np
import pytest

from jaxgeo.io import read_dem
from jaxgeo.io._geoid import SHIPPED_GRIDS, read_geoid
from tests.conftest import REPO

REAL = pathlib.Path(__file__).resolve().parents[1] / "data" / "real" / "ventoux" / "dem"
PROJ_CROP = REAL / "egm96_15_crop_lon3-8_lat42-47.gtx"  # a crop of PROJ's us_nga_egm96_15


def test_shipped_egm96_matches_projs_grid():
    """Both hold NGA's EGM96 15' values: ours in int16 centimetres, PROJ's in float32 metres."""
    shipped = read_geoid(SHIPPED_GRIDS["egm96"])
    proj = read_geoid(PROJ_CROP)
    rng = np.random.default_rng(0)
    lon, lat = rng.uniform(3.0, 8.0, 2000), rng.uniform(42.0, 47.0, 2000)
    diff = shipped(lon, lat) - proj(lon, lat)
    assert np.abs(diff).max() < 0.006  # the half centimetre of NGA's rounding to cm
    assert np.abs(proj(lon, lat)).min() > 40  # not two zero grids: N ~ 45-55 m here
    assert shipped.values_m.shape == (721, 1440)


def test_shipped_egm96_is_global_and_wraps():
    g = read_geoid(SHIPPED_GRIDS["egm96"])
    # the same meridian three ways, the last column to the first, both poles
    np.testing.assert_allclose(g(np.array([-180.0, 180.0, 540.0]), np.full(3, 10.0)),
                               g(-180.0, 10.0))  # fmt: skip
    east = g(179.875, 10.0)
    np.testing.assert_allclose(east, 0.5 * (g(179.75, 10.0) + g(-180.0, 10.0)), atol=1e-12)
    assert np.all(np.isfinite(g(np.array([0.0, 0.0]), np.array([-90.0, 90.0]))))
    # NGA's published extremes of EGM96: about -106.99 m (Indian Ocean) and +85.4 m (New Guinea)
    assert -107.0 < g.values_m.min() < -106.9 and 85.3 < g.values_m.max() < 85.5


def test_egm96_works_offline(tmp_path, monkeypatch):
    """A machine without PROJ's grid and without network: the PROJ data directories jaxgeo
    searches (PROJ_DATA, pyproj's) hold no geoid grid, ``geoid="egm96"`` still converts
    heights, with the shipped grid. (PROJ_DATA itself cannot name an empty folder: PROJ needs
    its proj.db there to know any CRS.)"""
    from jaxgeo.io import _geoid

    empty = tmp_path / "proj_data"
    empty.mkdir()
    monkeypatch.setattr(_geoid, "_proj_dirs", lambda: [empty])
    dem = read_dem(REAL / "N44E005_srtm90.tif", geoid="egm96")
    assert dem.geoid.source == str(SHIPPED_GRIDS["egm96"])
    assert "egm96_15.tif undulation" in dem.describe()
    ref = read_dem(REAL / "N44E005_srtm90.tif", geoid=PROJ_CROP)
    points = np.array([[5.2, 44.2], [5.01, 44.99], [5.5, 44.5]])
    np.testing.assert_allclose(dem(points), ref(points), atol=0.006)


def test_projs_grid_comes_first(tmp_path, monkeypatch):
    proj_dir = tmp_path / "proj"
    proj_dir.mkdir()
    shutil.copy(SHIPPED_GRIDS["egm96"], proj_dir / "us_nga_egm96_15.tif")
    monkeypatch.setenv("PROJ_DATA", str(proj_dir))
    assert read_geoid("egm96").source == str(proj_dir / "us_nga_egm96_15.tif")


def test_egm2008_says_where_to_get_it(monkeypatch):
    from jaxgeo.io import _geoid

    monkeypatch.setattr(_geoid, "_proj_dirs", lambda: [])
    with pytest.raises(
        ValueError,
        match=r"geoid 'egm2008': PROJ grid us_nga_egm08_25.tif not "
        r"found .*cdn.proj.org/us_nga_egm08_25.tif",
    ):
        read_geoid("egm2008")


def test_the_shipped_grid_is_package_data():
    """``pip install .`` carries it: pyproject's package data names jaxgeo/io/data."""
    import tomllib

    data = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "data/*.tif" in data["package-data"]["jaxgeo.io"]
    assert SHIPPED_GRIDS["egm96"].is_relative_to(REPO / "jaxgeo" / "io" / "data")
    assert 0.5e6 < SHIPPED_GRIDS["egm96"].stat().st_size < 3e6
