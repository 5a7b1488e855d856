"""Simulated Carto-2S strips (003_ sections 8-11): sub-scenes, overlaps, per-scene RPCs, files."""

import json
from collections import Counter

import numpy as np
import pytest

from jaxgeo import geodesy
from jaxgeo.io import read_ground, read_observations, read_rpc
from jaxgeo.models import localize_points, project_points
from jaxgeo.simulate import Carto2SStripSettings, SimulationError, carto2s_strip

N_SCENES = 6


@pytest.fixture(scope="module")
def strip():
    return carto2s_strip(N_SCENES, seed=3)


def test_sub_scene_layout(strip):
    assert strip.names == tuple(f"scene_{k:03d}" for k in range(N_SCENES))
    step = strip.scene_rows - strip.params["overlap_rows"]
    assert np.array_equal(strip.first_rows, np.arange(N_SCENES) * step)
    assert int(strip.truth_strip.n_rows) == strip.first_rows[-1] + strip.scene_rows
    # ~31 km x 15 km sub-scenes (003_ section 11)
    model = strip.truth_model(2)
    corners = localize_points(model, np.array([[0.0, 0.0], [23999.0, 0.0], [0.0, 47999.0]]), 500.0)
    across = np.linalg.norm(geodesy.geodetic_to_enu(corners[1], corners[0]))
    along = np.linalg.norm(geodesy.geodetic_to_enu(corners[2], corners[0]))
    print(f"sub-scene {along / 1e3:.1f} km x {across / 1e3:.1f} km")
    assert 28e3 < along < 34e3 and 13e3 < across < 17e3


def test_overlap_points_are_seen_in_both_scenes(strip):
    """A strip line in the overlap is one ray: same ground in scene k and k + 1 (tie points)."""
    k = 2
    offset = strip.first_rows[k + 1] - strip.first_rows[k]
    rows = np.linspace(offset, strip.scene_rows - 1, 7)  # overlap lines, in scene k
    image_k = np.stack([np.linspace(0.0, 23999.0, 7), rows], -1)
    inner = (image_k[:, 0] > 100) & (image_k[:, 0] < 23899)  # vendor cubes: the vendor footprint
    a, b = strip.truth_model(k), strip.truth_model(k + 1)
    ground = localize_points(a, image_k, 700.0)
    image_next = project_points(b, ground)
    assert np.abs(image_next - (image_k - [0.0, offset])).max() < 1e-6
    assert np.all((image_next[:, 1] >= 0) & (image_next[:, 1] <= strip.scene_rows - 1))
    # both vendor RPCs cover the overlap, and disagree there by their per-scene errors
    ra, rb = strip.vendor[strip.names[k]], strip.vendor[strip.names[k + 1]]
    assert bool(np.all(ra.in_domain(ground[inner]))) and bool(np.all(rb.in_domain(ground[inner])))
    jump = project_points(ra, ground) - (project_points(rb, ground) + [0.0, offset])
    print(f"vendor discontinuity at the overlap: {np.abs(jump).max():.2f} px")
    assert np.abs(jump).max() > 0.2


def test_points_roles_and_measurements(strip):
    gcp_scenes = {
        pid.split("_G")[0]
        for pid, r in zip(strip.ground.ids, strip.ground.role, strict=False)
        if r == "gcp"
    }
    assert gcp_scenes == {"scene_000", "scene_004", "scene_005"}  # every 4th and the last
    assert strip.ground.role.count("gcp") == 3 * 4
    assert strip.ground.role.count("check") == N_SCENES * 2
    seen = Counter(strip.observations.point_ids)
    assert set(seen) == set(strip.ground.ids) and max(seen.values()) <= 2
    # every measurement is the truth projection in its sub-scene (plus noise)
    index = {p: i for i, p in enumerate(strip.ground.ids)}
    for k, name in enumerate(strip.names):
        rows = [i for i, img in enumerate(strip.image_true.images) if img == name]
        g = strip.ground_true[[index[strip.image_true.point_ids[i]] for i in rows]]
        assert (
            np.abs(project_points(strip.truth_model(k), g) - strip.image_true.xy[rows]).max() < 1e-5
        )
    noise = strip.observations.xy - strip.image_true.xy
    assert 0.1 < np.std(noise) < 0.5


def test_per_scene_rpcs(strip):
    acc = strip.accuracy()
    print(json.dumps(acc["image_px"]))
    for name in strip.names:
        rep = strip.fit_reports[name]
        assert rep.check_rms_px < 0.01 and rep.check_max_px < 0.05
        assert 5.0 < acc["image_px"][name]["rms"] < 80.0  # ~13-19 m at 0.63 m (003_ table 1)
    # each RPC reproduces its own perturbed sub-scene model over its own scene (its validity
    # cube: far outside it an RPC extrapolates, and the last scene's cube lies ~9 normalised
    # units from the first scene's points)
    for k in (0, N_SCENES - 1):
        rpc = strip.vendor[strip.names[k]]
        ground = strip.ground_true[np.asarray(rpc.in_domain(strip.ground_true))]
        assert len(ground) >= 5
        d = project_points(rpc, ground) - project_points(strip.vendor_model(k), ground)
        assert np.abs(d).max() < 1e-3  # the fit check grid gives ~1e-5 px


def test_save_files_and_determinism(strip, tmp_path):
    paths = strip.save(tmp_path / "a")
    names = {p.name for p in paths}
    assert names == {f"scene_{k:03d}.txt" for k in range(N_SCENES)} | {
        "ground.csv",
        "observations.csv",
        "strip.json",
        "truth.json",
    }
    meta = json.loads((tmp_path / "a" / "strip.json").read_text())
    assert [s["first_line"] for s in meta["scenes"]] == strip.first_rows.tolist()
    assert all(s["n_rows"] == 48000 and s["n_cols"] == 24000 for s in meta["scenes"])
    assert [s["has_gcps"] for s in meta["scenes"]] == [True, False, False, False, True, True]
    rpc = read_rpc(tmp_path / "a" / meta["scenes"][1]["rpc"])
    assert np.array_equal(np.asarray(rpc.den), np.asarray(strip.vendor["scene_001"].den))
    assert len(read_ground(tmp_path / "a" / "ground.csv")) == len(strip.ground)
    assert len(read_observations(tmp_path / "a" / "observations.csv")) == len(strip.observations)
    with pytest.raises(FileExistsError):
        strip.save(tmp_path / "a")
    carto2s_strip(N_SCENES, seed=3).save(tmp_path / "b")
    for p in paths:
        assert p.read_bytes() == (tmp_path / "b" / p.name).read_bytes(), p.name


def test_bad_arguments():
    with pytest.raises(ValueError, match="n_scenes"):
        carto2s_strip(0)
    with pytest.raises(ValueError, match="overlap_rows"):
        carto2s_strip(2, settings=Carto2SStripSettings(overlap_rows=48000))
    for kwargs, setting in ((dict(gcp_every=0), "gcp_every"), (dict(line_time_s=-1.0),
                            "line_time_s"), (dict(rpc_scenes=(-1,)), "rpc_scenes"),
                            (dict(scene_rows=1), "scene_rows")):  # fmt: skip
        with pytest.raises(SimulationError, match=f"^{setting} must") as err:
            Carto2SStripSettings(**kwargs)
        assert err.value.setting == setting
    with pytest.raises(SimulationError, match=r"rpc_scenes must lie in \[0, n_scenes = 2\)"):
        carto2s_strip(2, settings=Carto2SStripSettings(rpc_scenes=(0, 2)))
