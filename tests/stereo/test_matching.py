"""``jaxgeo match`` on the s2p Pleiades triplet (images 1-2) against s2p's 481 tie points."""

import numpy as np

from jaxgeo.cli import main
from jaxgeo.io import read_observations, read_rpc
from jaxgeo.stereo import epipolar_offsets


def test_match_agrees_with_s2p_ties(shared_data, tmp_path):
    folder = shared_data / "s2p_triplet"
    img1, img2 = folder / "img_01.tif", folder / "img_02.tif"
    out = tmp_path / "obs.csv"
    # s2p's run: matches_on_rpc_roi(img_01, img_02, x=100, y=100, w=200, h=200)
    argv = ["match", str(img1), str(img2), "--roi", "100", "100", "200", "200"]
    assert main([*argv, "--heights", "0", "300", "-o", str(out)]) == 0
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
