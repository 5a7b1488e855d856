"""The simulators' settings objects: frozen, checked when made, a bad value named by its field."""

import dataclasses

import pytest

from jaxgeo.simulate import (
    Carto2SStripSettings,
    Cartosat1Settings,
    EphemerisSettings,
    RenderSettings,
    SimulationError,
    StereoSceneSettings,
)
from jaxgeo.simulate._stereo_scene_models import PleiadesSettings
from jaxgeo.simulate._tiepair import TiePairSettings

CAMERA = dict(sidereal_angle_rad=1.0, line_time_s=0.336e-3, n_rows=100, n_cols=100,
              focal_length_m=1.945, pixel_size_m=7e-6)  # fmt: skip


@pytest.mark.parametrize(
    "make, setting",
    [
        (lambda: EphemerisSettings(**CAMERA | dict(line_time_s=0.0)), "line_time_s"),
        (lambda: EphemerisSettings(**CAMERA | dict(n_rows=0)), "n_rows"),
        (lambda: EphemerisSettings(**CAMERA | dict(sidereal_angle_rad=float("nan"))),
         "sidereal_angle_rad"),
        (lambda: EphemerisSettings(**CAMERA | dict(velocity_order=-1)), "velocity_order"),
        (lambda: EphemerisSettings(**CAMERA | dict(attitude_order=5, n_samples=5)), "n_samples"),
        (lambda: RenderSettings(supersample=0), "supersample"),
        (lambda: RenderSettings(noise=-1.0), "noise"),
        (lambda: PleiadesSettings(altitude_m=-1.0), "altitude_m"),
        (lambda: TiePairSettings(gross_fraction=1.5), "gross_fraction"),
        (lambda: TiePairSettings(sigma_px=0.0), "sigma_px"),
        (lambda: StereoSceneSettings(relief_m=float("inf")), "relief_m"),
    ],
)  # fmt: skip
def test_bad_values_are_named(make, setting):
    with pytest.raises(SimulationError, match=f"^{setting} must") as err:
        make()
    assert err.value.setting == setting
    assert err.value.render({setting: "--option"}).startswith("--option must")


def test_settings_are_frozen_and_default_to_the_papers_missions():
    for settings in (Cartosat1Settings(), Carto2SStripSettings(), StereoSceneSettings(),
                     EphemerisSettings(**CAMERA), RenderSettings(), TiePairSettings()):  # fmt: skip
        with pytest.raises(dataclasses.FrozenInstanceError):
            settings.seed = 1
    assert Cartosat1Settings().view_angles_deg == (26.0, -5.0)  # 000_ table 1
    assert Carto2SStripSettings().scene_rows == 48000
    assert EphemerisSettings(**CAMERA).velocity_order is None  # the position's order
