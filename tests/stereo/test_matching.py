"""Guided SIFT matching: ``jaxgeo match`` on the s2p Pleiades triplet (images 1-2) against s2p's
481 tie points, and the candidate search's ratio test with SIFT's duplicate keypoints."""

import numpy as np
import pytest

from jaxgeo.cli import main
from jaxgeo.io import read_observations, read_rpc
from jaxgeo.stereo import epipolar_offsets, guided_matches
from jaxgeo.stereo._matching import epipolar_candidates


def test_match_agrees_with_s2p_ties(shared_data, tmp_path):
    folder = shared_data / "s2p_triplet"
    img1, img2 = folder / "img_01.tif", folder / "img_02.tif"
    out = tmp_path / "obs.csv"
    # s2p's run: matches_on_rpc_roi(img_01, img_02, x=100, y=100, w=200, h=200); defaults here
    argv = ["match", str(img1), str(img2), "--roi", "100", "100", "200", "200", "--quiet"]
    assert main([*argv, "-o", str(out)]) == 0
    assert main([*argv, "-o", str(out)]) == 2  # never overwrites
    obs = read_observations(out)
    xy1 = obs.xy[np.asarray(obs.images) == "img_01"]
    xy2 = obs.xy[np.asarray(obs.images) == "img_02"]
    assert len(xy1) == len(xy2) > 300
    assert np.all((xy1 > 99) & (xy1 < 300))
    m1, m2 = read_rpc(img1), read_rpc(img2)
    s2p = np.loadtxt(folder / "matches_on_rpc_roi_img01_img02.txt")
    ours = epipolar_offsets(m1, m2, xy1, xy2, (0.0, 300.0))
    theirs = epipolar_offsets(m1, m2, s2p[:, :2], s2p[:, 2:], (0.0, 300.0))
    # the relative bias (offset across the epipolar curve) both sets imply: -0.69 px each
    assert abs(np.median(ours) - np.median(theirs)) < 0.1
    assert np.std(ours) < 0.3


@pytest.fixture(scope="module")
def ventoux_models(real_data):
    return (
        read_rpc(real_data / "phr_ventoux__left_image.geom"),
        read_rpc(real_data / "phr_ventoux__right_image.geom"),
    )


def _descriptor(*weights):
    d = np.zeros(128, np.float32)
    d[: len(weights)] = weights
    return d / np.linalg.norm(d)


def test_ratio_test_ignores_other_orientations_of_the_same_keypoint(ventoux_models):
    left, right = ventoux_models
    xy1 = np.array([[14200.0, 16100.0]])
    true2 = np.asarray(right.project(left.localize(xy1[0], 800.0)))
    # along the epipolar segment, 80 m higher: another location the search sees
    other2 = np.asarray(right.project(left.localize(xy1[0], 880.0)))
    desc1 = _descriptor(1.0)[None]
    best, same_spot = _descriptor(1.0, 0.2), _descriptor(1.0, 0.22)  # distances ~0.20, ~0.22
    far = _descriptor(0.0, 1.0)
    # one keypoint at the true spot with two orientations (two descriptors), a far descriptor
    # elsewhere on the segment: the second orientation is not a rival, the match is kept
    xy2 = np.array([true2, true2, other2])
    c = epipolar_candidates(left, right, (xy1, desc1), (xy2, np.stack([best, same_spot, far])),
                            (500.0, 1500.0))  # fmt: skip
    assert len(c) == 1 and c.i2[0] == 0 and c.ratio[0] < 0.2
    # on the models' epipolar curve (its chord over 1000 m: 0.006 px away from the curve here)
    assert abs(c.across_px[0]) < 0.02
    # the same descriptor at another location of the segment is a rival: ambiguous, dropped
    c = epipolar_candidates(left, right, (xy1, desc1), (xy2, np.stack([best, far, same_spot])),
                            (500.0, 1500.0))  # fmt: skip
    assert len(c) == 0
    # outside the searched heights (the segment), nothing is a candidate
    c = epipolar_candidates(left, right, (xy1, desc1), (xy2, np.stack([best, same_spot, far])),
                            (1000.0, 1500.0))  # fmt: skip
    assert len(c) == 0


def test_guided_matches_keeps_its_interface(ventoux_models):
    left, right = ventoux_models
    rng = np.random.default_rng(0)
    xy1 = np.column_stack([rng.uniform(14000, 14400, 40), rng.uniform(15900, 16300, 40)])
    xy2 = np.asarray(right.project(left.localize(xy1, 800.0))) + [0.3, -0.2]
    desc = rng.random((40, 128)).astype(np.float32)
    m = guided_matches(left, right, (xy1, desc), (xy2, desc), (500.0, 1500.0), epipolar_tol_px=5.0)
    assert len(m) == m.n_candidates == 40
    np.testing.assert_allclose(m.xy1, xy1)
    np.testing.assert_allclose(m.xy2, xy2)
    np.testing.assert_allclose(m.across_px, np.median(m.across_px), atol=0.02)
