"""A stereo block on the real Pleiades Ventoux pair with injected image-space biases."""

import dataclasses

import numpy as np
import pytest

from jaxgeo import AffineBias, Biased
from jaxgeo.geodesy import metres_per_unit
from jaxgeo.io import GroundPoints, Observations, read_rpc

NOISE_PX = 0.3
GCP_SIGMA_M = 0.1  # GPS points on 0.5 m pixels: 0.2 px
TRUE_BIAS = {
    "left": AffineBias([12.0, -7.0], [[2e-5, -1e-5], [3e-5, 1e-5]]),
    "right": AffineBias([-5.0, 9.0], [[-1e-5, 2e-5], [1e-5, -2e-5]]),
}


@dataclasses.dataclass
class Block:
    models: dict  # the vendor RPCs, as delivered (biased)
    truth: dict  # the true geometry: Biased(rpc, TRUE_BIAS)
    ground: GroundPoints
    obs: Observations
    exact_xy: np.ndarray  # noise-free measurements, same order as obs


def make_block(
    left, right, n=30, n_gcp=6, noise=NOISE_PX, seed=0, gcp_sigma_m=GCP_SIGMA_M
) -> Block:
    """``n`` points in the Ventoux pair, the first ``n_gcp`` GCPs (coordinates with
    ``gcp_sigma_m`` noise, the sigma they are given), the rest check points (true coordinates);
    measurements: true projections + ``noise`` px."""
    rng = np.random.default_rng(seed)
    g = np.asarray(left.ground_offset) + rng.uniform(-0.8, 0.8, (n, 3)) * np.asarray(
        left.ground_scale
    )
    truth = {name: Biased(m, TRUE_BIAS[name]) for name, m in (("left", left), ("right", right))}
    ids = tuple(f"P{i:02d}" for i in range(n))
    role = tuple("gcp" if i < n_gcp else "check" for i in range(n))
    given = g.copy()
    enu_noise = rng.normal(0.0, gcp_sigma_m, (n_gcp, 3))
    given[:n_gcp] += enu_noise / metres_per_unit(g[:n_gcp], xp=np)
    ground = GroundPoints(ids, given, role, np.full((n, 3), gcp_sigma_m))
    exact = np.concatenate([np.asarray(m.project(g)) for m in truth.values()])
    xy = exact + rng.normal(0.0, noise, exact.shape)
    obs = Observations(ids * 2, ("left",) * n + ("right",) * n, xy, np.full(2 * n, noise))
    return Block({"left": left, "right": right}, truth, ground, obs, exact)


@pytest.fixture(scope="session")
def ventoux_pair(real_data):
    return (
        read_rpc(real_data / "phr_ventoux__left_image.geom"),
        read_rpc(real_data / "phr_ventoux__right_image.geom"),
    )


@pytest.fixture(scope="session")
def block(ventoux_pair) -> Block:
    return make_block(*ventoux_pair)
