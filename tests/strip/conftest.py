"""One simulated Carto-2S strip for the strip tests, simulated and adjusted once per session.

12 sub-scenes with GCPs surveyed in every one (``strip_full``); ``strip_quarter`` keeps the GCPs
of a quarter of them (every fourth and the last, the rule of 003_ section 9), and
``strip_result`` is its two-level adjustment with the default settings (robust loss, data
snooping) and 20 ties per pair: test_solve checks its accuracy and compares corrupted copies
of the strip with it (same shapes: the compiled solve is reused within that module).
"""

import warnings

import numpy as np
import pytest

from jaxgeo.simulate import Carto2SStripSettings, carto2s_strip
from jaxgeo.strip import (
    Level1Config,
    Level2Config,
    Strip,
    StripConfig,
    TieConfig,
    UniversalCorrectionWarning,
    adjust_strip,
)

N_SCENES = 12
QUARTER = (0, 4, 8, 11)
TIES = 20


def strip_config(degree="quadratic", solver=None, **level1):
    """The strip configuration of these tests: ``TIES`` ties per pair."""
    extra = {} if solver is None else {"solver": solver}
    return StripConfig(
        ties=TieConfig(per_pair=TIES),
        level1=Level1Config(**level1),
        level2=Level2Config(degree),
        **extra,
    )


@pytest.fixture(scope="session")
def strip_sim():
    return carto2s_strip(N_SCENES, seed=7, settings=Carto2SStripSettings(gcp_every=1))


@pytest.fixture(scope="session")
def strip_full(strip_sim):
    return Strip.from_simulation(strip_sim)


@pytest.fixture(scope="session")
def strip_quarter(strip_full):
    return strip_full.with_gcp_scenes(QUARTER)


@pytest.fixture(scope="session")
def strip_result(strip_quarter):
    # GCPs in level 1 already make it absolute: the quadratic of eq. 12-13 fitted to 4 GCP
    # scenes mostly fits their noise, and says so
    with pytest.warns(UniversalCorrectionWarning, match="quadratic universal correction"):
        return adjust_strip(strip_quarter, strip_config())


@pytest.fixture(scope="session")
def strip_ties_only(strip_quarter):
    """The paper's pure flow on ``strip_quarter``: level 1 with ties only (weak bias priors of
    50 px and 1e-4), the quadratic correction from the GCPs at level 2."""
    prior = np.array([50.0, 50.0, 1e-4, 1e-4, 1e-4, 1e-4])
    config = strip_config(use_gcps=False, bias_prior_sigma=prior)
    with warnings.catch_warnings():  # the quadratic from 4 GCP scenes: test_solve says so
        warnings.simplefilter("ignore", UniversalCorrectionWarning)
        return adjust_strip(strip_quarter, config)
