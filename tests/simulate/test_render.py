"""Rendered images of a simulated pair: pixels see the terrain through the true models."""

import numpy as np
import pytest

from jaxgeo.simulate._render import cartosat1_rendered, localize_on_terrain, render, write_image

SIZE = 160


@pytest.fixture(scope="module")
def rendered():
    return cartosat1_rendered(3, size=SIZE)


def test_pixels_see_the_terrain_through_the_true_model(rendered):
    scene = rendered.scene
    xy = np.random.default_rng(0).uniform(0, SIZE - 1, (300, 2))
    for name in scene.names:
        ground = localize_on_terrain(scene.truth[name], scene.terrain, xy)
        assert np.all(np.isfinite(ground))
        # on the terrain, and seen at the pixel by the true model (LOS nodes every 8 px)
        np.testing.assert_allclose(ground[:, 2], scene.terrain.height_np(ground[:, :2]), atol=1e-4)
        back = np.asarray(scene.truth[name].project(ground))
        assert np.abs(back - xy).max() < 5e-3


def test_images_are_textured_deterministic_and_consistent(rendered, tmp_path):
    fore, aft = (rendered.images[n] for n in rendered.scene.names)
    assert fore.shape == aft.shape == (SIZE, SIZE) and fore.dtype == np.uint16
    for img in (fore, aft):  # contrast everywhere: no flat 16 x 16 block
        blocks = img.reshape(SIZE // 16, 16, SIZE // 16, 16).astype(float).std(axis=(1, 3))
        assert blocks.min() > 5.0 and img.std() > 100.0
    # fore and aft see the same ground: warped onto the fore grid, aft correlates with it
    import cv2

    scene = rendered.scene
    yx = np.mgrid[40:120, 40:120].reshape(2, -1).T.astype(float)
    g = localize_on_terrain(scene.truth["fore"], scene.terrain, yx[:, ::-1])
    xa = np.asarray(scene.truth["aft"].project(g)).astype(np.float32).reshape(80, 80, 2)
    warped = cv2.remap(aft.astype(np.float32), xa[..., 0], xa[..., 1], cv2.INTER_CUBIC)
    assert np.corrcoef(warped.ravel(), fore[40:120, 40:120].ravel())[0, 1] > 0.9
    assert rendered.gsd_m == pytest.approx(2.44, abs=0.1)  # Cartosat-1 fore camera
    # deterministic in the seed
    model, terrain = scene.truth["aft"], scene.terrain
    a, b = (render(model, terrain, rendered.texture, (24, 24), np.random.default_rng(5))
            for _ in range(2))  # fmt: skip
    np.testing.assert_array_equal(a, b)
    path = write_image(fore, tmp_path / "fore.tif")
    with pytest.raises(FileExistsError):
        write_image(fore, path)
