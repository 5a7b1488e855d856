"""A small real block for the engine's tests: the Ventoux Pleiades pair, 30 ties, 6 GCPs."""

import pytest

from jaxgeo import AffineBias, Biased
from jaxgeo.bundle import prepare
from jaxgeo.io import read_rpc
from tests.bundle.conftest import make_block


@pytest.fixture(scope="module")
def block_problem(real_data):
    """The block as a :class:`jaxgeo.lsq.Problem` (observations sorted by block)."""
    left = read_rpc(real_data / "phr_ventoux__left_image.geom")
    right = read_rpc(real_data / "phr_ventoux__right_image.geom")
    block = make_block(left, right, n=30, n_gcp=6)
    models = {name: Biased(m, AffineBias()) for name, m in block.models.items()}
    return prepare(models, block.obs, block.ground).problem
