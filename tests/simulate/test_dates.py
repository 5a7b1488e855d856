"""Several dates of one simulated site (``StereoSceneSettings.site_seed``, ``view_angle_deg``,
``change``): the same ground seen by other images, and a known height change."""

import numpy as np
import pytest

from jaxgeo.simulate import (
    SimulationError,
    StereoSceneSettings,
    Terrain,
    TerrainChange,
    stereo_scene_truth,
)

SIZE = 128


def test_site_seed_gives_the_ground_of_that_seed_seen_by_other_images():
    first = stereo_scene_truth(SIZE, 3)
    change = TerrainChange(height_m=-8.0, east_m=10.0, north_m=-5.0, sigma_m=12.0)
    second = stereo_scene_truth(SIZE, 4, StereoSceneSettings(site_seed=3, view_angle_deg=8.0,
                                                             change=change))  # fmt: skip
    for name in ("wavevectors_rad_m", "amplitudes", "phases_rad", "raw_min", "raw_max"):
        assert np.array_equal(getattr(first.terrain, name), getattr(second.terrain, name))
    assert int(first.texture.key) == int(second.texture.key)
    # other images: other vendor errors, a smaller base (8 deg instead of 11.3)
    vendor = [s.info["rpc_vs_truth"]["left"]["nojitter_px"]["mean_xy"] for s in (first, second)]
    assert not np.allclose(*vendor)
    assert second.info["base_to_height"] < 0.8 * first.info["base_to_height"]
    assert second.info["params"]["site_seed"] == 3 and "site_seed" not in first.info["params"]
    # the change: -8 m at its centre, nothing far from it, the rest of the ground the same
    t = second.terrain
    lon0, lat0 = float(t.centre_lon_deg), float(t.centre_lat_deg)
    deg_e = 1.0 / (6_371_008.8 * np.cos(np.radians(lat0)) * np.pi / 180)
    deg_n = 1.0 / (6_371_008.8 * np.pi / 180)
    at = np.array([[lon0 + 10 * deg_e, lat0 - 5 * deg_n], [lon0 + 80 * deg_e, lat0]])
    assert t.change_np(at) == pytest.approx([-8.0, 0.0], abs=1e-6)
    assert t.height_np(at) - first.terrain.height_np(at) == pytest.approx([-8.0, 0.0], abs=1e-6)
    assert np.asarray(t.height(at)) == pytest.approx(t.height_np(at))  # jax and numpy agree
    # site_seed equal to the seed changes nothing
    same = stereo_scene_truth(SIZE, 3, StereoSceneSettings(site_seed=3))
    assert np.array_equal(same.points, first.points)
    assert np.array_equal(same.info["rpc_vs_truth"]["left"]["nojitter_px"]["mean_xy"],
                          first.info["rpc_vs_truth"]["left"]["nojitter_px"]["mean_xy"])  # fmt: skip


def test_terrain_without_changes_reads_back_and_bad_changes_are_named():
    t = stereo_scene_truth(SIZE, 3).terrain
    d = t.to_dict()
    assert "changes" not in d  # a single date's truth.json: as before changes existed
    assert Terrain.from_dict(d).changes.shape == (0, 4)
    moved = Terrain.from_dict(t.with_changes(TerrainChange()).to_dict())
    assert moved.changes.tolist() == [[0.0, 0.0, 40.0, -20.0]]
    for kwargs, name in (({"sigma_m": 0.0}, "sigma_m"), ({"height_m": float("nan")}, "height_m")):
        with pytest.raises(SimulationError, match=f"^{name} must") as err:
            TerrainChange(**kwargs)
        assert err.value.setting == name
    with pytest.raises(SimulationError, match="^view_angle_deg must"):
        StereoSceneSettings(view_angle_deg=0.0)
    with pytest.raises(SimulationError, match="^site_seed must"):
        StereoSceneSettings(site_seed=-1)


def test_cli_names_the_option_of_a_bad_change(tmp_path, capsys):
    from jaxgeo.cli import main

    argv = ["simulate", "stereo-scene", "--size", "64", "--out", str(tmp_path / "s")]
    assert main([*argv, "--change", "-5", "0", "0", "0"]) == 2
    err = capsys.readouterr().err
    assert "--change must be > 0 (m), got 0.0" in err and err.count("\n") == 1
    assert main([*argv, "--view-angle", "45"]) == 2
    assert "--view-angle must be in [1, 30]" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()
