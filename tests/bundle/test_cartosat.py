"""Tables 3-5 of 000_5aba1cb50921f3c6.txt on the embedded simulated Cartosat-1 scene.

The scene (jaxgeo/data/cartosat1_demo, made by jaxgeo.simulate with a fixed seed): a fore/aft
pair with 2.5 m pixels, vendor RPCs biased by ~30 px, 9 GCPs and 60 check points in one quarter
of the scene, 0.3 px measurement noise, a priori sigmas 0.5 px and 0.3 m as in the paper.
"""

import dataclasses

import numpy as np
import pytest

from jaxgeo.bundle import adjust, direct_georeferencing
from jaxgeo.io import read_ground, read_observations, read_rpc
from jaxgeo.simulate import demo_dir

GSD_M = 2.5


@pytest.fixture(scope="module")
def scene():
    d = demo_dir()
    models = {"fore": read_rpc(d / "fore.txt"), "aft": read_rpc(d / "aft.txt")}
    return models, read_ground(d / "ground.csv"), read_observations(d / "observations.csv")


@pytest.fixture(scope="module")
def tables(scene):
    models, ground, obs = scene
    out = {"direct": direct_georeferencing(models, obs, ground, roles=("check",))}
    for bias in ("shift", "shift-drift", "affine"):
        out[bias] = adjust(models, obs, ground, bias=bias)
    return out


def test_direct_georeferencing_is_tens_of_metres_off(tables):
    d = tables["direct"]  # table 3: ~33 px offsets, ~72 m planimetry, ~25 m height
    assert d.n == 60
    assert d.images["fore"][1] > 20.0 and d.images["aft"][1] > 20.0
    assert np.hypot(d.rms_m[0], d.rms_m[1]) > 30.0 and d.rms_m[2] > 5.0


@pytest.mark.parametrize("bias", ["shift", "shift-drift", "affine"])
def test_bias_corrected_rpcs_reach_sub_pixel(tables, bias):
    res = tables[bias]  # table 4
    rep = res.report
    assert res.converged and rep.n == 60
    assert rep.rms_m[0] < 0.5 * GSD_M and rep.rms_m[1] < 0.5 * GSD_M  # sub-pixel planimetry
    assert rep.rms_m[2] < 1.0 * GSD_M  # about 1 px in height
    for name in ("fore", "aft"):
        assert max(rep.images[name][:2]) < 0.6  # image RMS at check points (px)
    assert 0.4 < res.s0 < 0.9  # noise 0.3 px against an a priori 0.5 px


def test_minimal_control(scene, tables):
    models, ground, obs = scene  # table 5: shift with 1 GCP, shift+drift with 3 GCPs
    gcps = [p for p, r in zip(ground.ids, ground.role, strict=True) if r == "gcp"]
    one = adjust(models, obs, ground.with_roles({p: "check" for p in gcps[1:]}), bias="shift")
    three = adjust(
        models, obs, ground.with_roles({p: "check" for p in gcps[3:]}), bias="shift-drift"
    )
    for res, n_check in ((one, 68), (three, 66)):
        rep = res.report
        assert res.converged and rep.n == n_check
        assert np.hypot(rep.rms_m[0], rep.rms_m[1]) < GSD_M and rep.rms_m[2] < 2.5 * GSD_M
    # one GCP cannot be as good as nine
    assert one.report.rms_m[2] > tables["shift"].report.rms_m[2]


def test_drift_and_affine_errors_give_the_ordering_of_table_4(scene):
    """Real Cartosat-1 RPC errors had drift and affine parts (table 4); the simulated vendor errors
    are almost a pure shift. Add to the fore image an along-track drift (1.5 px over the scene)
    and a rotation (~1 px at the edges): heights and image RMS then order shift > shift+drift >
    affine, as in the paper."""
    models, ground, obs = scene
    x, y = obs.xy[:, 0], obs.xy[:, 1]
    fore = np.array([img == "fore" for img in obs.images])[:, None]
    drift_rot = np.stack([1.5e-4 * (y - 6000.0), 1.25e-4 * y + 1.5e-4 * (x - 6000.0)], axis=1)
    distorted = dataclasses.replace(obs, xy=obs.xy + fore * drift_rot)
    kinds = ("shift", "shift-drift", "affine")
    res = {b: adjust(models, distorted, ground, bias=b) for b in kinds}
    h = [res[b].report.rms_m[2] for b in kinds]
    img_y = [res[b].report.images["fore"][1] for b in kinds]
    assert h[0] > h[1] > h[2] and img_y[0] > img_y[1] > img_y[2]
    assert res["shift"].s0 > max(res["shift-drift"].s0, res["affine"].s0)
    assert res["affine"].report.rms_m[2] < 1.0 * GSD_M
