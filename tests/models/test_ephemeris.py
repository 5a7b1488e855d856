"""The polynomial-ephemeris rigorous model (003_ section 2): orbit, frames, project/localize."""

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxgeo import geodesy
from jaxgeo.models import EphemerisModel
from jaxgeo.models import localize_points as localize
from jaxgeo.models import project_points as project
from jaxgeo.models.internal import gmst_rad
from jaxgeo.rotations import angles_from_matrix, omega_phi_kappa
from jaxgeo.simulate import CircularOrbit, EphemerisSettings, ephemeris_from_orbit
from jaxgeo.simulate._orbit import ground_track_attitude, sun_synchronous_inclination_deg

LON, LAT = 147.30, -42.88  # Hobart
N = 12000
LINE_TIME = 0.336e-3
eqx_jit = eqx.filter_jit


def cartosat1_camera(view_deg: float, t_centre: float, span=(-80.0, 40.0)) -> EphemerisModel:
    theta0 = gmst_rad("2006-10-01T00:40:00Z")
    orbit = CircularOrbit.over(LON, LAT, 618e3, sun_synchronous_inclination_deg(618e3), theta0)
    wobble = np.array([[3e-6, -2e-6, 1e-6], [-4e-6, 1e-6, 0.0], [2e-6, 0.0, 1e-6]])
    return ephemeris_from_orbit(
        orbit, span, EphemerisSettings(sidereal_angle_rad=theta0,
        line_time_s=LINE_TIME, n_rows=N, n_cols=N, focal_length_m=1.945, pixel_size_m=7e-6,
        h_ref_m=500.0), first_line_time_s=t_centre - (N - 1) / 2 * LINE_TIME,
        view_angles_deg=(view_deg, 0.0, 0.0), attitude_offsets_rad=wobble,
    )  # fmt: skip


@pytest.fixture(scope="module")
def fore():
    return cartosat1_camera(26.0, -44.6)


@pytest.fixture(scope="module")
def aft():
    return cartosat1_camera(-5.0, 7.9)


def image_points(n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, N - 1, (n, 2)), rng.uniform(-100.0, 1400.0, n)


def test_sun_synchronous_inclination_and_gmst():
    # Cartosat-1: 618 km, 97.87 deg (ISRO); GMST 1992-08-20 12:14 UT1 = 152.578787810 deg
    # (Vallado, Fundamentals of Astrodynamics, example 3-5); J2000 epoch 280.46061837 deg
    assert sun_synchronous_inclination_deg(618e3) == pytest.approx(97.87, abs=0.02)
    assert math.degrees(gmst_rad("1992-08-20T12:14:00Z")) == pytest.approx(152.578787810, abs=1e-5)
    assert math.degrees(gmst_rad("2000-01-01T12:00:00")) == pytest.approx(280.46061837, abs=1e-8)


def test_circular_orbit_passes_over_target():
    theta0 = 1.234
    orbit = CircularOrbit.over(LON, LAT, 618e3, 97.87, theta0, t_over_s=10.0)
    pos, vel = orbit.state([0.0, 10.0, 600.0])
    assert np.allclose(np.linalg.norm(pos, axis=-1), geodesy.WGS84_A_M + 618e3, atol=1e-6)
    assert np.allclose(
        np.linalg.norm(vel, axis=-1), math.sqrt(geodesy.GM_EARTH_M3_S2 / orbit.radius_m)
    )
    assert np.allclose(np.sum(pos * vel, -1), 0.0, atol=1e-3)
    # at t_over the radius vector (rotated into ECEF) points at the target, descending
    theta = theta0 + geodesy.OMEGA_EARTH_RAD_S * 10.0
    c, s = math.cos(theta), math.sin(theta)
    ecef = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) @ pos[1]
    target = np.asarray(geodesy.geodetic_to_ecef(jnp.array([LON, LAT, 0.0])))
    cos_angle = ecef @ target / np.linalg.norm(ecef) / np.linalg.norm(target)
    assert math.acos(min(cos_angle, 1.0)) < 1e-9
    assert vel[1, 2] < 0.0


def test_polynomials_follow_the_kepler_orbit(fore):
    theta0 = float(fore.sidereal_angle_rad)
    orbit = CircularOrbit.over(LON, LAT, 618e3, sun_synchronous_inclination_deg(618e3), theta0)
    t = np.linspace(-80.0, 40.0, 57)
    pos, vel = orbit.state(t)
    p, v = fore.state_eci(jnp.asarray(t))
    assert np.abs(np.asarray(p) - pos).max() < 1.5  # m: a cubic (003_) over 120 s of orbit
    assert np.abs(np.asarray(v) - vel).max() < 1e-3  # m/s


def test_yaw_steering_aligns_body_with_ground_track():
    orbit = CircularOrbit.over(LON, LAT, 618e3, 97.87, 0.3)
    pos, vel = orbit.state(np.linspace(-30, 30, 7))
    angles = ground_track_attitude(pos, vel)
    # only yaw, of a few degrees (Earth rotation ~ 340 m/s vs ground speed ~ 6.9 km/s)
    assert np.abs(angles[:, :2]).max() < 1e-12
    assert 2.0 < np.degrees(np.abs(angles[:, 2])).min() < 4.5
    r = np.asarray(omega_phi_kappa(*angles.T))
    assert np.allclose(angles_from_matrix(r), angles, atol=1e-14)


def test_project_localize_round_trip(fore, aft):
    image, h = image_points(2000)
    # also a CCD line off the principal point and a mounting with all three angles
    skewed = dataclasses.replace(
        fore, ccd_offset_m=jnp.asarray(2e-3), view_angles_rad=jnp.array([0.45, 0.01, 0.002])
    )
    for model in (fore, aft, skewed):
        ground = localize(model, image, h)
        assert np.allclose(ground[:, 2], h, atol=0.0)
        back = project(model, ground)
        err = np.abs(np.asarray(back) - image).max()
        print(f"round trip image -> ground -> image: {err:.2e} px")
        assert err < 1e-6
        again = localize(model, back, h)
        d = np.asarray(geodesy.geodetic_to_ecef(again) - geodesy.geodetic_to_ecef(ground))
        assert np.abs(d).max() < 1e-5  # m


def test_localized_point_lies_on_the_image_ray(fore):
    image, h = image_points(50, seed=1)
    ground = localize(fore, image, h)
    centre, d = fore.image_ray(jnp.asarray(image))
    v = np.asarray(geodesy.geodetic_to_ecef(ground) - centre)
    off_ray = np.linalg.norm(v - np.sum(v * np.asarray(d), -1)[:, None] * np.asarray(d), axis=-1)
    assert off_ray.max() < 1e-6  # m
    # collinearity: in the CCD frame the point is on the scan line (x = 0) at the pixel's y
    t = fore.row_time(jnp.asarray(image[:, 1]))
    cam = jnp.einsum("nji,nj->ni", fore.camera_to_ecef(t), jnp.asarray(v))
    ys = np.asarray(fore.focal_length_m * cam[:, 1] / -cam[:, 2] / fore.pixel_size_m)
    assert np.abs(np.asarray(cam[:, 0] / cam[:, 2])).max() < 1e-12
    assert np.allclose(ys + float(fore.principal_col_px), image[:, 0], atol=1e-6)


def test_view_geometry_matches_cartosat1(fore, aft):
    centre = np.array([5999.5, 5999.5])
    g_fore = localize(fore, centre, 0.0)[0]
    # the fore camera looks ~26 deg ahead: its footprint lies ahead of the nadir point
    t = fore.row_time(5999.5)
    pos_eci, vel_eci = fore.state_eci(t)
    theta = fore.sidereal_angle(t)
    q = np.array([[np.cos(theta), np.sin(theta), 0], [-np.sin(theta), np.cos(theta), 0], [0, 0, 1]])
    sat = q @ np.asarray(pos_eci)
    look = np.asarray(geodesy.geodetic_to_ecef(g_fore)) - sat
    off_nadir = math.degrees(math.acos(-look @ sat / np.linalg.norm(look) / np.linalg.norm(sat)))
    assert off_nadir == pytest.approx(26.0, abs=1.5)  # Earth curvature adds a little
    # across-track ground sampling at the centre (000_ table 1: fore 2.452 m, aft 2.187 m)
    for model, gsd in ((fore, 2.452), (aft, 2.187)):
        g = localize(model, jnp.array([[5999.0, 5999.5], [6000.0, 5999.5]]), 0.0)
        e = np.asarray(geodesy.geodetic_to_enu(g, g[0]))
        assert np.linalg.norm(e[1]) == pytest.approx(gsd, rel=0.06)
    # columns grow to the left of the flight direction: east on a descending pass
    g = localize(fore, jnp.array([[0.0, 6000.0], [11999.0, 6000.0]]), 0.0)
    assert g[1, 0] > g[0, 0]


def test_batch_shapes(fore):
    # shapes by abstract evaluation (no compilation), values on one batched call
    shape = lambda f, *a: jax.eval_shape(f, *a).shape  # noqa: E731
    for batch in [(), (1,), (3, 1, 2)]:
        image = jax.ShapeDtypeStruct((*batch, 2), jnp.float64)
        ground = jax.ShapeDtypeStruct((*batch, 3), jnp.float64)
        h = jax.ShapeDtypeStruct(batch, jnp.float64)
        assert shape(fore.localize, image, h) == (*batch, 3)
        assert shape(fore.project, ground) == (*batch, 2)
    image = jax.ShapeDtypeStruct((4, 1, 2), jnp.float64)
    assert shape(fore.localize, image, jax.ShapeDtypeStruct((5,), jnp.float64)) == (4, 5, 3)
    rng = np.random.default_rng(2)
    image = rng.uniform(0, N - 1, (3, 1, 2, 2))
    ground = eqx_jit(lambda m, i: m.localize(i, 500.0))(fore, image)
    assert ground.shape == (3, 1, 2, 3)
    back = eqx_jit(lambda m, g: m.project(g))(fore, ground)
    assert back.shape == (3, 1, 2, 2) and np.allclose(back, image, atol=1e-6)


def test_gradients(fore):
    # check_grads (float64): project w.r.t. ground (local ENU metres) and attitude coefficients,
    # orders 1 (forward and reverse) and 2 (forward: the implicit-function derivative rule of
    # the scan-time solve differentiated again); localize w.r.t. image coordinates, order 1.
    origin = np.asarray(localize(fore, np.array([3000.0, 8000.0]), 300.0))[0]

    @jax.jit
    def of_project(enu, att):
        model = dataclasses.replace(fore, attitude_coeffs=att)
        return model.project(geodesy.enu_to_geodetic(enu, origin))

    @jax.jit
    def of_localize(xy):
        return geodesy.geodetic_to_enu(fore.localize(xy, 300.0), origin)

    x = (jnp.array([10.0, -20.0, 5.0]), fore.attitude_coeffs)
    check_grads(of_project, x, 1, modes=("fwd", "rev"), eps=1e-6, rtol=1e-5)
    check_grads(of_project, x, 2, modes=("fwd",), eps=1e-6, rtol=1e-5)
    xy = (jnp.array([3000.0, 8000.0]),)
    check_grads(of_localize, xy, 1, modes=("fwd", "rev"), eps=1e-3, rtol=1e-5)


def test_dict_round_trip_and_rows(fore):
    back = EphemerisModel.from_dict(fore.to_dict())
    g = np.array([[LON, LAT, 200.0], [LON + 0.05, LAT - 0.03, 800.0]])
    assert np.array_equal(project(back, g), project(fore, g))
    with pytest.raises(KeyError, match="unknown field"):
        EphemerisModel.from_dict({**fore.to_dict(), "bogus": 1})
    # a sub-scene cut at a line offset sees the same point 1000 rows earlier
    sub = fore.with_rows(1000.0, 5000)
    assert int(sub.n_rows) == 5000
    assert np.allclose(project(sub, g), project(fore, g) - np.array([0.0, 1000.0]), atol=1e-6)
    with pytest.raises(ValueError, match="image size"):
        dataclasses.replace(fore, n_rows=0)
