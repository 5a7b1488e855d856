"""Test set-up: float64 on, a fixed path to the shared real data."""

import os
import pathlib

import jax
import pytest

jax.config.update("jax_enable_x64", True)

REPO = pathlib.Path(__file__).resolve().parents[1]
REAL_DATA = pathlib.Path(
    os.environ.get("JAXGEO_REAL_DATA", REPO.parent / "shared" / "data" / "real")
)


@pytest.fixture(scope="session")
def real_data() -> pathlib.Path:
    if not REAL_DATA.is_dir():
        raise FileNotFoundError(
            f"real test data not found at {REAL_DATA}; set JAXGEO_REAL_DATA to ../shared/data/real"
        )
    return REAL_DATA
