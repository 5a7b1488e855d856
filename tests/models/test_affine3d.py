"""3D affine model (eq. 1 of 000_): exact recovery, round trips, gradients, a physical truth."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxgeo import geodesy
from jaxgeo.models import Affine3D, KeplerSequence, SceneMetadata
from jaxgeo.models._affine3d import SPACES, to_object

CENTRE = np.array([147.3, -42.9, 300.0])  # Hobart (000_), UTM zone 55 south


def _ground(n, rng, extent_deg=0.05, h=(0.0, 1200.0)):
    lon = CENTRE[0] + rng.uniform(-extent_deg, extent_deg, n)
    lat = CENTRE[1] + rng.uniform(-extent_deg, extent_deg, n)
    return np.stack([lon, lat, rng.uniform(*h, n)], axis=-1)


def _true_affine(space, rng):
    """An affine model whose image of the test area is roughly a 12000 x 12000 scene."""
    g = _ground(50, rng)
    obj = np.asarray(to_object(g, space, 55, False))
    lin = np.array([[1.0, 0.1, 0.3], [-0.1, -1.0, 0.05]])  # x ~ east, y ~ south, some height
    scale = 12000.0 / np.ptp(obj[:, :2], axis=0).max()
    img = (obj - obj.mean(axis=0)) @ (lin.T * scale) + 6000.0
    return Affine3D.fit(g, img, space=space, zone=55, north=False)


@pytest.mark.parametrize("space", SPACES)
def test_fit_recovers_exact_affine(space):
    rng = np.random.default_rng(0)
    truth = _true_affine(space, rng)
    raw = np.asarray(truth.raw_parameters())
    g = _ground(12, rng)
    model = Affine3D.fit(g, truth.project(g), space=space, zone=55, north=False)
    np.testing.assert_allclose(np.asarray(model.raw_parameters()), raw, rtol=1e-8, atol=1e-9)
    check = _ground(30, rng)
    err = np.asarray(model.project(check) - truth.project(check))
    assert np.abs(err).max() < 1e-7
    # the paper's a1..a8 rebuild the same model
    again = Affine3D.from_raw(raw, space, CENTRE, zone=55, north=False)
    assert np.abs(np.asarray(again.project(check) - truth.project(check))).max() < 1e-6


@pytest.mark.parametrize("space", SPACES)
def test_round_trip(space):
    rng = np.random.default_rng(1)
    model = _true_affine(space, rng)
    g = _ground(40, rng)
    x = model.project(g)
    back = model.localize(x, g[:, 2])
    again = model.project(back)
    assert np.abs(np.asarray(again - x)).max() < 1e-6
    assert np.abs(np.asarray(back - g)).max() < 1e-9  # deg, and h passes through


@pytest.mark.parametrize("space", ["utm", "geocentric"])
@pytest.mark.parametrize("shape", [(), (5,), (2, 3)])
def test_batch_shapes(space, shape):
    rng = np.random.default_rng(2)
    model = _true_affine(space, rng)
    g = _ground(int(np.prod(shape)), rng).reshape(*shape, 3)
    x = model.project(g)
    assert x.shape == (*shape, 2)
    back = model.localize(x, g[..., 2])
    assert back.shape == (*shape, 3)
    np.testing.assert_allclose(np.asarray(back), g, atol=1e-9)


@pytest.mark.parametrize("space", SPACES)
def test_gradients(space):
    rng = np.random.default_rng(3)
    model = _true_affine(space, rng)
    g = jnp.asarray(_ground(3, rng))
    params, static = eqx.partition(model, eqx.is_inexact_array)

    def project(q, p):  # w.r.t. ground and the parameter leaf together
        return eqx.combine(p, static).project(q)

    check_grads(project, (g, params), order=2, modes=("fwd", "rev"))

    def localize_m(x):  # lon/lat scaled to ~metres so the tolerance means something
        return model.localize(x, g[:, 2])[..., :2] * 1e5

    # eps 0.01 px: lon/lat carry ~3 um of rounding, too much for a 1e-4 px difference step
    order = 1 if space == "geocentric" else 2  # geocentric: Newton + implicit differentiation
    check_grads(localize_m, (model.project(g),), order=order, modes=("fwd", "rev"), eps=1e-2)


def test_too_few_and_coplanar_gcps():
    rng = np.random.default_rng(4)
    g = _ground(10, rng)
    img = rng.uniform(0, 12000, (10, 2))
    with pytest.raises(ValueError, match="at least 4 non-coplanar GCPs .* got 3"):
        Affine3D.fit(g[:3], img[:3])
    flat = g.copy()
    flat[:, 2] = 250.0  # one height: coplanar in UTM and geographic space
    for space in ("utm", "geographic"):
        with pytest.raises(ValueError, match=f"the 10 GCPs are \\(near-\\)coplanar in {space}"):
            Affine3D.fit(flat, img, space=space)
    # one height over 4 km is curved in ECEF by only ~5e-5 of the extent: near-coplanar
    small = _ground(10, rng, extent_deg=0.02, h=(250.0, 250.0))
    with pytest.raises(ValueError, match="the 10 GCPs are \\(near-\\)coplanar in geocentric"):
        Affine3D.fit(small, img, space="geocentric")
    tilted = g.copy()  # on an inclined plane in UTM, plus 1 mm noise
    utm = np.asarray(geodesy.geodetic_to_utm(g, 55, False))
    tilted[:, 2] = 0.05 * (utm[:, 0] - utm[:, 0].mean()) + 1e-3 * rng.normal(size=10) + 500.0
    with pytest.raises(ValueError, match="the 10 GCPs are \\(near-\\)coplanar in utm"):
        Affine3D.fit(tilted, img, space="utm", zone=55, north=False)
    bad = g.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite GCP.*7"):
        Affine3D.fit(bad, img)
    with pytest.raises(ValueError, match="unknown object space"):
        Affine3D.fit(g, img, space="lcc")


def _nadir_truth():
    """A rigorous near-nadir pushbroom (Kepler model, Cartosat-1 camera, 618 km, 12000 px)."""
    half = 0.17  # ~15 km half-width at 43 deg S, the scene footprint of a 2.5 m, 12000 px line
    corners = [
        [CENTRE[0] - half * 1.3, CENTRE[1] + half, 0.0],
        [CENTRE[0] + half * 1.3, CENTRE[1] + half, 0.0],
        [CENTRE[0] + half * 1.3, CENTRE[1] - half, 0.0],
        [CENTRE[0] - half * 1.3, CENTRE[1] - half, 0.0],
    ]
    scene = SceneMetadata("nadir", 12000, 12000, corners, 618e3, 0.0, 0.0, 1945.0, 7.0, 0.336e-3)
    return KeplerSequence.from_metadata([scene]).image(0)


def test_fit_to_rigorous_nadir_truth_is_subpixel():
    """Affine3D from 12 GCPs in a 2000 x 2000 px (5 km) window with 0-500 m relief.

    The truth is a perspective pushbroom, so the affine model is an approximation: the residual
    at the 30 check points is its approximation error (no noise is added). Over the whole
    30 km scene with 0-1500 m relief the same fit is several times worse.
    """
    truth = eqx.filter_jit(_nadir_truth().localize)
    rng = np.random.default_rng(5)
    rms = {}
    for window, (lo, hi), relief in (
        ("5 km", (5000.0, 7000.0), 500.0),
        ("30 km", (0, 11999), 1500.0),
    ):
        px = rng.uniform(lo, hi, (42, 2))
        ground = np.asarray(truth(px, rng.uniform(0.0, relief, 42)))
        for space in SPACES:
            model = Affine3D.fit(ground[:12], px[:12], space=space)
            res = np.asarray(model.project(ground[12:])) - px[12:]
            rms[window, space] = float(np.sqrt((res**2).mean()))
    print("affine check-point rms (px):", {k: round(v, 3) for k, v in rms.items()})
    assert rms["5 km", "utm"] < 0.5
    assert max(rms["5 km", s] for s in SPACES) < 1.0
    assert min(rms["30 km", s] for s in SPACES) > 2.0 * rms["5 km", "utm"]
