"""Geodesy against pyproj (PROJ): ECEF, ENU (topocentric), UTM forward/inverse; gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads
from pyproj import Transformer

from jaxgeo import geodesy

N_POINTS = 2000


def _random_geodetic(rng, n, lon0=0.0, half_width=180.0, lat=(-89.9, 89.9), h=(-500.0, 9000.0)):
    return np.stack(
        [
            rng.uniform(lon0 - half_width, lon0 + half_width, n),
            rng.uniform(*lat, n),
            rng.uniform(*h, n),
        ],
        axis=-1,
    )


@settings(max_examples=10, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1), high=st.booleans())
def test_ecef_matches_pyproj_and_round_trips(seed, high):
    rng = np.random.default_rng(seed)
    h = (4.0e5, 9.0e5) if high else (-500.0, 9000.0)  # orbit altitudes too
    g = _random_geodetic(rng, N_POINTS, h=h)
    ours = np.asarray(geodesy.geodetic_to_ecef(g))
    ref = np.array(Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(*g.T)).T
    assert np.abs(ours - ref).max() < 1e-6  # metres
    back = np.asarray(geodesy.ecef_to_geodetic(ours))
    lon_err = ((back[:, 0] - g[:, 0] + 180) % 360 - 180) * 111320 * np.cos(np.deg2rad(g[:, 1]))
    assert np.abs(lon_err).max() < 1e-6
    assert np.abs(back[:, 1] - g[:, 1]).max() * 111320 < 1e-6
    assert np.abs(back[:, 2] - g[:, 2]).max() < 1e-6


@settings(max_examples=15, deadline=None, derandomize=True)
@given(zone=st.integers(1, 60), seed=st.integers(0, 2**31 - 1), north=st.booleans())
def test_utm_matches_pyproj_over_the_zone(zone, seed, north):
    rng = np.random.default_rng(seed)
    cm = geodesy.utm_central_meridian(zone)
    lat = (0.0, 84.0) if north else (-80.0, 0.0)
    g = _random_geodetic(rng, N_POINTS, lon0=cm, half_width=3.0, lat=lat)
    epsg = geodesy.utm_epsg(zone, north)
    ref = np.array(
        Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True).transform(
            g[:, 0], g[:, 1]
        )
    ).T
    ours = np.asarray(geodesy.geodetic_to_utm(g, zone, north))
    assert np.abs(ours[:, :2] - ref).max() < 1e-3  # < 1 mm, the bar
    assert np.abs(ours[:, :2] - ref).max() < 1e-5  # what Krueger n^6 actually gives
    np.testing.assert_array_equal(ours[:, 2], g[:, 2])
    back = np.asarray(geodesy.utm_to_geodetic(ours, zone, north))
    # inverse against pyproj's inverse, in metres on the ground
    ref_inv = np.array(
        Transformer.from_crs(f"EPSG:{epsg}", "EPSG:4326", always_xy=True).transform(
            ours[:, 0], ours[:, 1]
        )
    ).T
    for ll in (g[:, :2], ref_inv):
        d_lon = (back[:, 0] - ll[:, 0]) * 111320 * np.cos(np.deg2rad(ll[:, 1]))
        d_lat = (back[:, 1] - ll[:, 1]) * 110574
        assert np.abs(d_lon).max() < 1e-3 and np.abs(d_lat).max() < 1e-3


@settings(max_examples=10, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1))
def test_enu_matches_proj_topocentric(seed):
    rng = np.random.default_rng(seed)
    origin = _random_geodetic(rng, 1, lat=(-85, 85))[0]
    g = origin + np.stack(
        [rng.uniform(-0.5, 0.5, 500), rng.uniform(-0.5, 0.5, 500), rng.uniform(-500, 3000, 500)],
        axis=-1,
    )
    ours = np.asarray(geodesy.geodetic_to_enu(g, origin))
    topo = Transformer.from_pipeline(
        "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        "+step +proj=cart +ellps=WGS84 "
        "+step +proj=topocentric +ellps=WGS84 "
        f"+lon_0={float(origin[0])!r} +lat_0={float(origin[1])!r} "
        f"+h_0={float(origin[2])!r}"
    )
    ref = np.array(topo.transform(g[:, 0], g[:, 1], g[:, 2])).T
    assert np.abs(ours - ref).max() < 1e-6
    back = np.asarray(geodesy.enu_to_geodetic(ours, origin))
    d_lon = (back[:, 0] - g[:, 0] + 180.0) % 360.0 - 180.0  # longitudes wrap at the antimeridian
    assert np.abs(d_lon).max() < 1e-11 and np.abs(back[:, 1] - g[:, 1]).max() < 1e-11
    assert np.abs(back[:, 2] - g[:, 2]).max() < 1e-6


def test_utm_zone_helpers():
    assert geodesy.utm_zone(7.05) == 32
    assert geodesy.utm_zone(-180.0) == 1 and geodesy.utm_zone(179.99) == 60
    assert geodesy.utm_central_meridian(32) == 9.0
    assert geodesy.utm_epsg(55, north=False) == 32755
    with pytest.raises(ValueError, match="UTM zone"):
        geodesy.utm_central_meridian(0)


@pytest.mark.parametrize("shape", [(), (1,), (3, 1, 2)])
def test_batch_shapes(shape):
    rng = np.random.default_rng(1)
    g = _random_geodetic(rng, int(np.prod(shape, dtype=int)), lat=(-60, 60)).reshape(*shape, 3)
    assert geodesy.geodetic_to_ecef(g).shape == (*shape, 3)
    assert geodesy.ecef_to_geodetic(geodesy.geodetic_to_ecef(g)).shape == (*shape, 3)
    assert geodesy.geodetic_to_utm(g, 31).shape == (*shape, 3)
    assert geodesy.geodetic_to_enu(g, np.array([0.0, 0.0, 0.0])).shape == (*shape, 3)


@pytest.mark.usefixtures("finite_differences_on_cpu")
def test_jit_and_gradients():
    g = jnp.array([[7.05, 43.7, 120.0], [10.3, -42.9, 1260.0]])
    origin = jnp.array([7.0, 43.6, 0.0])
    f = jax.jit(geodesy.geodetic_to_ecef)
    np.testing.assert_allclose(f(g), geodesy.geodetic_to_ecef(g), rtol=0, atol=1e-9)
    for fn in (
        geodesy.geodetic_to_ecef,
        lambda x: geodesy.ecef_to_geodetic(geodesy.geodetic_to_ecef(x)),
        lambda x: geodesy.geodetic_to_utm(x, 32),
        lambda x: geodesy.utm_to_geodetic(geodesy.geodetic_to_utm(x, 32), 32),
        lambda x: geodesy.geodetic_to_enu(x, origin),
    ):
        check_grads(fn, (g,), order=2, modes=("fwd", "rev"), eps=1e-4, atol=1e-5, rtol=1e-5)
    # the round trip is the identity: its Jacobian too
    jac = jax.jacfwd(lambda x: geodesy.utm_to_geodetic(geodesy.geodetic_to_utm(x, 32), 32))(g[0])
    np.testing.assert_allclose(jac, np.eye(3), atol=1e-10)


# ------------------------------------------------------------------------ metres per unit


def test_metres_per_unit_equals_ecef_derivatives_from_pyproj():
    """Metres per degree lon/lat and per metre h: the lengths of the ECEF displacements of a
    small step, with ECEF from pyproj (central differences) and from autodiff of our ECEF."""
    g = _random_geodetic(np.random.default_rng(7), 200, lat=(-85.0, 85.0), h=(-500.0, 9.0e5))
    ours = np.asarray(geodesy.metres_per_unit(g))
    assert ours.shape == (200, 3)
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    steps = np.array([1e-5, 1e-5, 1.0])  # deg, deg, m
    for k in range(3):
        plus, minus = g.copy(), g.copy()
        plus[:, k] += steps[k]
        minus[:, k] -= steps[k]
        diff = np.array(to_ecef.transform(*plus.T)).T - np.array(to_ecef.transform(*minus.T)).T
        numeric = np.linalg.norm(diff, axis=-1) / (2 * steps[k])
        np.testing.assert_allclose(ours[:, k], numeric, rtol=1e-8)
    jac = jax.vmap(jax.jacfwd(geodesy.geodetic_to_ecef))(jnp.asarray(g))  # (n, 3 xyz, 3 llh)
    np.testing.assert_allclose(ours, np.linalg.norm(np.asarray(jac), axis=-2), rtol=1e-12)


@pytest.mark.parametrize("batch", [(), (1,), (3, 1, 2)])
def test_metres_per_unit_batches_and_numpy_twin(batch):
    rng = np.random.default_rng(8)
    g = _random_geodetic(rng, int(np.prod(batch, dtype=int)), h=(-500.0, 9000.0))
    g = g.reshape(*batch, 3)
    ours = geodesy.metres_per_unit(g)
    assert ours.shape == (*batch, 3) and ours.dtype == jnp.float64
    host = geodesy.metres_per_unit(g, xp=np)
    assert isinstance(host, np.ndarray) and host.shape == (*batch, 3)
    np.testing.assert_allclose(host, np.asarray(ours), rtol=1e-15, atol=0.0)
    np.testing.assert_allclose(np.asarray(jax.jit(geodesy.metres_per_unit)(g)), np.asarray(ours))
    # at the equator and h = 0: a * pi / 180 per degree of longitude
    eq = np.asarray(geodesy.metres_per_unit(np.array([10.0, 0.0, 0.0])))
    np.testing.assert_allclose(eq[0], geodesy.WGS84_A_M * np.pi / 180.0, rtol=1e-15)


def test_metres_per_unit_gradients():
    g = jnp.array([[7.2, 44.1, 1500.0], [-70.0, -33.5, 20.0]])
    check_grads(geodesy.metres_per_unit, (g,), order=2, modes=("fwd", "rev"), eps=1e-3)


# ------------------------------------------------------------------------ ECEF near a point


@settings(max_examples=10, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1))
def test_ecef_near_a_point_equals_ecef_to_rounding(seed):
    """The trigonometry-free ECEF of a point given by its offset from a reference equals
    ``geodetic_to_ecef`` of the point to rounding up to ``OFFSET_MAX_RAD`` (and the series
    alone, the sines and cosines, to 4e-16); 1e-12 relative at 1 rad."""
    rng = np.random.default_rng(seed)
    a0 = rng.uniform(-np.pi, np.pi, N_POINTS)
    lim = geodesy.OFFSET_MAX_RAD
    d = rng.uniform(-lim, lim, N_POINTS)
    s, c = geodesy.sincos_near(np.sin(a0), np.cos(a0), d)
    np.testing.assert_allclose(s, np.sin(a0 + d), rtol=0, atol=4e-16)
    np.testing.assert_allclose(c, np.cos(a0 + d), rtol=0, atol=4e-16)
    far = rng.uniform(-1.0, 1.0, N_POINTS)
    s, _ = geodesy.sincos_near(np.sin(a0), np.cos(a0), far)
    np.testing.assert_allclose(s, np.sin(a0 + far), rtol=0, atol=1e-12)
    ref = _random_geodetic(rng, N_POINTS)
    offset = rng.uniform(-lim, lim, (N_POINTS, 2))
    point = ref + np.concatenate([np.rad2deg(offset), np.zeros((N_POINTS, 1))], axis=1)
    point[:, 1] = np.clip(point[:, 1], -90.0, 90.0)
    offset[:, 1] = np.deg2rad(point[:, 1] - ref[:, 1])
    near = geodesy.geodetic_to_ecef_near(geodesy.lonlat_trig(ref), offset, point[:, 2])
    # 2e-8 m: the offsets rounded to degrees in ``point`` (1e-14 deg ~ 1e-9 m) and ECEF's ulp
    np.testing.assert_allclose(near, geodesy.geodetic_to_ecef(point), rtol=0, atol=2e-8)


def test_ecef_near_a_point_gradients():
    """First order (forward and reverse) against finite differences: second differences of
    6e6 m coordinates are rounding noise at any step."""
    trig0 = geodesy.lonlat_trig(jnp.array([[7.05, 43.7, 0.0], [-120.3, -42.9, 0.0]]))
    offset = jnp.array([[1e-4, -3e-5], [0.15, -0.18]])
    h = jnp.array([120.0, 1260.0])
    check_grads(
        geodesy.geodetic_to_ecef_near, (trig0, offset, h), order=1, modes=("fwd", "rev"),
        eps=1e-4, atol=1e-5, rtol=1e-5,
    )  # fmt: skip
