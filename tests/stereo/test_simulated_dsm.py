"""The stereo chain on a rendered Cartosat-1 pair against the true surface (issue 13, item 5),
and dense matching in bands of epipolar rows against one pass."""

import dataclasses

import numpy as np
import pytest

from jaxgeo.models import fit_rpcs
from jaxgeo.simulate._dsm_truth import height_errors
from jaxgeo.simulate._render import cartosat1_rendered
from jaxgeo.stereo import DSMSettings, rasterize, stereo_pair

SIZE = 320


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    rendered = cartosat1_rendered(0, size=SIZE)
    scene = rendered.scene
    paths = rendered.save_images(tmp_path_factory.mktemp("rendered"))
    # the true models as RPCs (fit error ~1e-7 px; the rigorous model projects iteratively)
    models = [scene.truth[n] for n in scene.names]
    truth = [rpc for rpc, _ in fit_rpcs(models, h_range=(100.0, 600.0))]
    return rendered, [paths[n] for n in scene.names], truth


def test_dsm_of_true_models_within_a_gsd_of_the_true_surface(pair):
    rendered, paths, truth = pair
    products = stereo_pair(truth, paths, DSMSettings(triangulation="los_midpoint"))
    dsm = rasterize(products.points, 2.0 * rendered.gsd_m)
    err = height_errors(dsm, rendered.scene.terrain, truth, [(SIZE, SIZE)] * 2, rendered.gsd_m)
    assert err["n_cells"] > 5000 and err["fill"] > 0.9, err
    assert err["rmse_gsd"] < 1.5, err  # the bar; measured ~0.4 GSD
    assert 0.0 < err["le90_gsd"] < 1.0 and abs(err["mean_gsd"]) < 0.3, err


def test_bands_of_epipolar_rows_match_one_pass(pair):
    _, paths, truth = pair
    roi = (60, 60, 200, 200)
    settings = DSMSettings(roi=roi, triangulation="los_midpoint", band_rows=None)
    one = stereo_pair(truth, paths, settings, keep=True)
    calls = []
    banded = stereo_pair(
        truth, paths, dataclasses.replace(settings, band_rows=48), keep=True,
        on_band=lambda done, total: calls.append((done, total)),
    )  # fmt: skip
    assert banded.stats["n_bands"] == 5 and calls[-1] == (5, 5) and len(calls) == 5
    d1, d2 = one.intermediates["disparity"], banded.intermediates["disparity"]
    assert d1.shape == d2.shape
    both = np.isfinite(d1) & np.isfinite(d2)
    assert both.sum() > 0.97 * np.isfinite(d1).sum()
    assert np.mean(np.abs(d1 - d2)[both] < 0.05) > 0.95  # SGM paths reach past 32 rows
    # the same epipolar image (each band samples from its own window: float32 map rounding)
    np.testing.assert_allclose(one.intermediates["left"], banded.intermediates["left"], atol=0.01)
    a = rasterize(one.points, 5.0)
    b = rasterize(banded.points, 5.0, epsg=a.epsg, origin=(a.x0, a.y0), shape=a.height.shape)
    dh = np.abs(a.height - b.height)[np.isfinite(a.height) & np.isfinite(b.height)]
    assert dh.size > 0.97 * np.isfinite(a.height).sum() and np.percentile(dh, 99) < 0.5
