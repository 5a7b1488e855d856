"""GCP distribution rule (003_ section 9) and the universal correction (003_ eq. 12-13)."""

import warnings

import numpy as np
import pytest

from jaxgeo.strip import GCPDistributionWarning, check_gcp_distribution
from jaxgeo.strip._universal import UniversallyCorrected, fit_universal_correction
from tests.conftest import cube_points


def test_every_fourth_scene_is_enough():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = check_gcp_distribution(80, range(1, 80, 4))  # 1, 5, ..., 77: gaps of 3
    assert res.ok and res.gcp_scenes[-1] == 77
    # 0, 4, ..., 76: no run of four without GCP, but none among the last three (77-79)
    with pytest.warns(GCPDistributionWarning, match="last three"):
        res = check_gcp_distribution(80, range(0, 80, 4))
    assert not res.gaps and not res.missing_head and res.missing_tail and not res.ok


def test_paper_example_of_40_scenes():
    # "any one of 1,2,3 and any one of 4,5,6,7 and any one of 8,9,10,11 ... and 38, 39, 40"
    one_based = [2, 5, 9, 13, 17, 21, 25, 29, 33, 37, 39]
    res = check_gcp_distribution(40, [i - 1 for i in one_based], warn=False)
    assert res.ok, res.message()


def test_gaps_are_named():
    names = [f"S{i:02d}" for i in range(20)]
    with pytest.warns(GCPDistributionWarning) as rec:
        res = check_gcp_distribution(20, [1, 2, 10, 19], names=names)
    assert res.gaps == ((3, 9), (11, 18))
    msg = str(rec[0].message)
    assert "S03..S09" in msg and "S11..S18" in msg and "7 consecutive" in msg
    with pytest.raises(ValueError, match="outside the strip"):
        check_gcp_distribution(5, [7])


def test_universal_correction_recovers_a_quadratic(pleiades):
    rpc, _ = pleiades
    rng = np.random.default_rng(0)
    level1 = cube_points(rpc, 30, seed=21)
    lat_n = (level1[:, 1] - level1[:, 1].mean()) / 0.05
    lon_n = (level1[:, 0] - level1[:, 0].mean()) / 0.05
    true_dlat = 2e-4 + 1e-5 * lat_n - 3e-6 * lon_n**2 + 2e-6 * lat_n * lon_n
    true_dlon = -1e-4 + 2e-5 * lon_n + 1e-6 * lat_n**2
    truth = level1.copy()
    truth[:, 0] += true_dlon
    truth[:, 1] += true_dlat
    corr, resid = fit_universal_correction(level1, truth)
    assert np.abs(resid).max() < 1e-12
    # interpolates to new points too
    other = cube_points(rpc, 10, seed=22, fraction=0.5)
    fixed = np.asarray(corr.apply(other))
    lat_n = (other[:, 1] - level1[:, 1].mean()) / 0.05
    lon_n = (other[:, 0] - level1[:, 0].mean()) / 0.05
    exp_lat = other[:, 1] + 2e-4 + 1e-5 * lat_n - 3e-6 * lon_n**2 + 2e-6 * lat_n * lon_n
    np.testing.assert_allclose(fixed[:, 1], exp_lat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(corr.invert(fixed)), other, rtol=0, atol=1e-12)
    # the corrected model maps true ground to the image where level 1 saw it
    model = UniversallyCorrected(rpc, corr)
    img = np.asarray(rpc.project(level1))
    np.testing.assert_allclose(np.asarray(model.project(truth)), img, rtol=0, atol=1e-7)
    back = np.asarray(model.localize(img, truth[:, 2]))
    np.testing.assert_allclose(back, truth, rtol=0, atol=1e-10)
    del rng


def test_universal_correction_needs_enough_gcps(pleiades):
    rpc, _ = pleiades
    g = cube_points(rpc, 5, seed=23)
    with pytest.raises(ValueError, match="at least 6 GCPs, got 5"):
        fit_universal_correction(g, g)
    corr, _ = fit_universal_correction(g, g + [1e-4, 0, 0], degree="affine")
    np.testing.assert_allclose(np.asarray(corr.delta(g))[:, 0], 1e-4, atol=1e-15)
    line = np.tile(g[:1], (8, 1))
    line[:, 1] += np.linspace(0, 0.1, 8)  # all GCPs on one meridian
    with pytest.raises(ValueError, match="not determined"):
        fit_universal_correction(line, line)
