"""Generic spline pushbroom (000_ eq. 3-4, sections 3.3.1-3.3.2) against an independent truth.

The truth is a Cartosat-1-like fore camera written here in numpy/pyproj/scipy (nothing from
jaxgeo): a circular orbit 618 km up, inclination 97.87 deg, descending over Hobart, expressed in
ECEF with the Earth's rotation; a body frame that follows the orbit (ECEF velocity) with small
constant roll/pitch/yaw offsets; a line camera tilted +26 deg forward, focal length 1945 mm,
pixel 7 um, 12000 x 12000 px, 0.336 ms per line, columns growing to the left of the flight.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from pyproj import Transformer
from scipy.interpolate import BSpline
from scipy.optimize import brentq

from jaxgeo import GenericPushbroom
from jaxgeo.models import SceneMetadata, Spline
from jaxgeo.models._pushbroom import mounting_rotation
from jaxgeo.models._spline import SplineObservations
from jaxgeo.models.internal import newton_root
from tests.typecheck import unchecked

GM_M3_S2 = 398600.4418e9
OMEGA_EARTH = 7.2921151467e-5
A_M, B_M = 6378137.0, 6378137.0 * (1 - 1 / 298.257223563)
N_PX = 12000
_ECEF = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


def _to_ecef(g):
    g = np.asarray(g, float)
    return np.stack(_ECEF.transform(g[..., 0], g[..., 1], g[..., 2]), -1)


def _to_geodetic(p):
    p = np.asarray(p, float)
    return np.stack(_ECEF.transform(p[..., 0], p[..., 1], p[..., 2], direction="INVERSE"), -1)


def _rot(axis, a):
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.eye(3)
    m[i, i] = m[j, j] = c
    m[i, j], m[j, i] = -s, s
    return m


class CartosatTruth:
    """A rigorous line camera on a circular orbit (see the module docstring)."""

    def __init__(self, altitude_m=618e3, rpy_rad=(1e-4, -2e-4, 3e-4), alpha_deg=26.0):
        self.r = 6371008.8 + altitude_m
        self.incl = np.deg2rad(97.87)
        self.n_mean = np.sqrt(GM_M3_S2 / self.r**3)
        self.line_time, self.focal_px = 0.336e-3, 1945e-3 / 7e-6
        self.x0 = (N_PX - 1) / 2
        self.alpha = np.deg2rad(alpha_deg)
        self.t_c = (N_PX - 1) / 2 * self.line_time
        self.u_c = np.pi - np.arcsin(np.sin(np.deg2rad(-40.4)) / np.sin(self.incl))  # descending
        self.raan = 0.0
        p = self.position_velocity(self.t_c)[0]
        self.raan = np.deg2rad(147.3) - np.arctan2(p[1], p[0])
        self.bias = _rot(0, rpy_rad[0]) @ _rot(1, rpy_rad[1]) @ _rot(2, rpy_rad[2])

    def position_velocity(self, t):
        """ECEF position and velocity at ``t`` (ECI = ECEF at t = 0)."""
        u = self.u_c + self.n_mean * (t - self.t_c)
        co, so, ci, si = np.cos(self.raan), np.sin(self.raan), np.cos(self.incl), np.sin(self.incl)
        cu, su = np.cos(u), np.sin(u)
        pos = self.r * np.array([co * cu - so * su * ci, so * cu + co * su * ci, su * si])
        vel = (
            self.r
            * self.n_mean
            * np.array([-co * su - so * cu * ci, -so * su + co * cu * ci, cu * si])
        )
        rz = _rot(2, -OMEGA_EARTH * t)
        return rz @ pos, rz @ (vel - np.cross([0.0, 0.0, OMEGA_EARTH], pos))

    def body(self, t):
        """Body axes (columns along, left, up) in ECEF."""
        s, v = self.position_velocity(t)
        z = s / np.linalg.norm(s)
        y = np.cross(z, v)
        y /= np.linalg.norm(y)
        return np.stack([np.cross(y, z), y, z], -1) @ self.bias

    def _camera(self, t):
        b = self.body(t)
        sa, ca = np.sin(self.alpha), np.cos(self.alpha)
        view, ccd, normal = b @ [sa, 0.0, -ca], b @ [0.0, 1.0, 0.0], b @ [ca, 0.0, sa]
        return self.position_velocity(t)[0], view, ccd, normal

    def project(self, ground):
        ground = np.asarray(ground, float)
        out = []
        for p in _to_ecef(ground.reshape(-1, 3)):
            scan = lambda t, p=p: self._camera(t)[3] @ (p - self._camera(t)[0])
            t = brentq(scan, self.t_c - 20, self.t_c + 20, xtol=1e-14, rtol=1e-15)
            s, view, ccd, _ = self._camera(t)
            d = p - s
            out.append([self.x0 + self.focal_px * (d @ ccd) / (d @ view), t / self.line_time])
        return np.array(out).reshape(*ground.shape[:-1], 2)

    def localize_on_ellipsoid(self, image):
        out = []
        for x, y in np.asarray(image, float).reshape(-1, 2):
            s, view, ccd, _ = self._camera(y * self.line_time)
            d = view + (x - self.x0) / self.focal_px * ccd
            o, e = s / [A_M, A_M, B_M], d / [A_M, A_M, B_M]
            qa, qb, qc = e @ e, 2 * o @ e, o @ o - 1
            out.append(_to_geodetic(s + (-qb - np.sqrt(qb * qb - 4 * qa * qc)) / (2 * qa) * d))
        return np.array(out)


def _metadata(truth, **overrides):
    corners = truth.localize_on_ellipsoid(
        [[0, 0], [N_PX - 1, 0], [N_PX - 1, N_PX - 1], [0, N_PX - 1]]
    )
    fields = dict(
        image_id="fore", n_cols=N_PX, n_rows=N_PX, corners=corners, flying_height_m=618e3,
        along_track_angle_deg=26.0, focal_length_mm=1945.0, pixel_size_um=7.0,
        line_time_s=0.336e-3,
    )  # fmt: skip
    fields.update(overrides)
    return SceneMetadata(**fields)


def _points(truth, n, seed, margin=200.0):
    """Ground points over the scene, heights 0..1300 m (Hobart), and their true image points."""
    rng = np.random.default_rng(seed)
    ground = truth.localize_on_ellipsoid(rng.uniform(margin, N_PX - 1 - margin, (n, 2)))
    ground[:, 2] = rng.uniform(0.0, 1300.0, n)
    return ground, truth.project(ground)


_N_PAD = 512  # every jitted call below runs on this many points: one compile for the file


@eqx.filter_jit
def _project_jit(m, g):
    return m.project(g)


@eqx.filter_jit
def _localize_jit(m, i, h):
    return m.localize(i, h)


def _pad(a):
    a = np.asarray(a, float)
    assert len(a) <= _N_PAD
    return np.concatenate([a, np.repeat(a[:1], _N_PAD - len(a), axis=0)])


def _project(m, ground):
    return np.asarray(_project_jit(m, _pad(ground)))[: len(ground)]


def _localize(m, image, h):
    return np.asarray(_localize_jit(m, _pad(image), _pad(h)))[: len(image)]


@pytest.fixture(scope="module")
def truth():
    return CartosatTruth()


@pytest.fixture(scope="module")
def model(truth):
    return GenericPushbroom.from_metadata(_metadata(truth))


@pytest.fixture(scope="module")
def perturbed(model):
    """The initial model with a non-trivial attitude and orbit: exercises every term of eq. 3."""
    rng = np.random.default_rng(7)
    att = rng.normal(scale=2e-4, size=model.attitude.coeffs.shape)
    orb = rng.normal(scale=200.0, size=model.orbit.coeffs.shape)
    return eqx.tree_at(
        lambda m: (m.attitude.coeffs, m.orbit.coeffs, m.camera_offset_m),
        model,
        (model.attitude.coeffs + att, model.orbit.coeffs + orb, jnp.array([1.0, -2.0, 0.5])),
    )


def test_mounting_rotation_is_eq4():
    for a_deg, b_deg in [(26.0, 0.0), (-5.0, 0.0), (26.0, 3.0), (-5.0, -12.0)]:
        a, b = np.deg2rad(a_deg), np.deg2rad(b_deg)
        r = np.asarray(mounting_rotation(a, b))
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-15)
        assert np.isclose(np.linalg.det(r), 1.0)
        z0 = np.array([np.tan(a), -np.tan(b), -1.0])
        np.testing.assert_allclose(r[:, 2], -z0 / np.linalg.norm(z0), atol=1e-15)
        np.testing.assert_allclose(r[:, 0], [0.0, np.cos(b), -np.sin(b)], atol=1e-15)
    np.testing.assert_allclose(mounting_rotation(0.0, 0.0), [[0, -1, 0], [1, 0, 0], [0, 0, 1]])


def test_equals_truth_when_given_the_true_orbit_and_attitude(truth, model):
    """Eq. 3 itself: splines fitted to the truth's orbit and attitude reproduce the truth."""
    t = np.linspace(0.0, (N_PX - 1) * truth.line_time, 41)
    r_o = truth.body(truth.t_c) @ truth.bias.T  # the orbit frame at the scene centre
    rpy = []
    for ti in t:
        r_p = r_o.T @ truth.body(ti)  # R_P = R_x(roll) R_y(pitch) R_z(yaw)
        rpy.append(
            [
                np.arctan2(-r_p[1, 2], r_p[2, 2]),
                np.arcsin(r_p[0, 2]),
                np.arctan2(-r_p[0, 1], r_p[0, 0]),
            ]
        )
    pos = np.array([truth.position_velocity(ti)[0] for ti in t])
    exact = eqx.tree_at(
        lambda m: (m.orbit, m.attitude, m.rotation_orbit),
        model,
        (Spline.fit(t, pos, t[0], t[-1]), Spline.fit(t, np.array(rpy), t[0], t[-1]), r_o),
    )
    ground, image = _points(truth, 40, seed=11, margin=0.0)
    err = np.abs(_project(exact, ground) - image).max()
    print(f"\nmodel with the true orbit/attitude (quadratic fits) vs truth: max {err:.2e} px")
    assert err < 1e-2  # what a quadratic leaves of a circular orbit over 4 s


def test_initialisation_from_metadata(truth, model):
    """Section 3.3.1: the circular orbit at R + H sees the row centres M_F, M_L at rows 0, n-1."""
    meta = _metadata(truth)
    c = meta.corners
    m_f = [(c[0, 0] + c[1, 0]) / 2, (c[0, 1] + c[1, 1]) / 2, 0.0]
    m_l = [(c[3, 0] + c[2, 0]) / 2, (c[3, 1] + c[2, 1]) / 2, 0.0]
    got = _project(model, np.array([m_f, m_l]))
    np.testing.assert_allclose(got, [[(N_PX - 1) / 2, 0.0], [(N_PX - 1) / 2, N_PX - 1]], atol=0.01)
    t = np.linspace(0.0, (N_PX - 1) * 0.336e-3, 9)
    radius = np.linalg.norm(np.asarray(model.orbit(t)), axis=-1)
    geocentric = np.linalg.norm(_to_ecef(np.array([m_f, m_l])), axis=-1).mean()
    np.testing.assert_allclose(radius, geocentric + 618e3, atol=0.05)
    np.testing.assert_allclose(model.attitude.coeffs, 0.0)
    np.testing.assert_allclose(model.focal_px, 1945.0 / 7.0 * 1e3)
    # the circle fulfils its own soft constraints (plane through the Earth centre, circular)
    assert np.abs(np.asarray(model.prior_residuals())).max() < 1e-4


def test_missing_line_time_and_focal_length_are_derived(truth, model):
    derived = GenericPushbroom.from_metadata(
        _metadata(truth, line_time_s=None, focal_length_mm=None, pixel_size_um=None)
    )
    line_time, focal = float(derived.line_time_s), float(derived.focal_px)
    print(
        f"\nderived line time {line_time * 1e3:.4f} ms (true 0.336), F {focal:.0f} px (true 277857)"
    )
    assert abs(line_time / 0.336e-3 - 1) < 0.02
    assert abs(focal / truth.focal_px - 1) < 0.05


def test_round_trip_over_the_whole_scene(perturbed):
    rng = np.random.default_rng(3)
    n = 400
    image = rng.uniform(-0.5, N_PX - 0.5, (n, 2))
    image[:4] = [[0, 0], [N_PX - 1, 0], [N_PX - 1, N_PX - 1], [0, N_PX - 1]]
    image[4:8, 1] = [-3000.0, -1000.0, N_PX + 1000.0, N_PX + 3000.0]  # beyond the scene's ends
    h = rng.uniform(-100.0, 4000.0, n)
    ground = _localize(perturbed, image, h)
    assert np.all(np.isfinite(ground))
    np.testing.assert_array_equal(ground[:, 2], h)
    back = _project(perturbed, ground)
    err = np.abs(back - image).max()
    # project -> localize -> project
    ground2 = _localize(perturbed, back, h)
    err2 = np.abs(_project(perturbed, ground2) - back).max()
    print(f"\nround trips over 12000 x 12000 px: {err:.1e} px, {err2:.1e} px")
    assert err < 1e-6 and err2 < 1e-6
    # the solved time puts the point in the scan plane (y_F = 0)
    y_f = perturbed.focal_plane(jnp.asarray(_to_ecef(ground)), perturbed.time_of_row(back[:, 1]))
    assert np.abs(np.asarray(y_f)[:, 1]).max() < 1e-6


@pytest.mark.parametrize("shape", [(), (5,), (2, 3)])
def test_batch_shapes(perturbed, shape):
    g = jax.ShapeDtypeStruct((*shape, 3), jnp.float64)
    assert jax.eval_shape(perturbed.project, g).shape == (*shape, 2)
    i = jax.ShapeDtypeStruct((*shape, 2), jnp.float64)
    h = jax.ShapeDtypeStruct(shape, jnp.float64)
    assert jax.eval_shape(perturbed.localize, i, h).shape == (*shape, 3)
    assert jax.eval_shape(perturbed.localize, i, 100.0).shape == (*shape, 3)


def test_batch_values(perturbed, truth):
    """A (2, 3) batch gives the values of the same points one by one."""
    ground, _ = _points(truth, 6, seed=4)
    flat = _project(perturbed, ground)
    g = ground.reshape(2, 3, 3)

    @eqx.filter_jit
    def both(m, g):
        image = m.project(g)
        return image, m.localize(image, g[..., 2])

    image, back = both(perturbed, g)
    assert image.shape == (2, 3, 2) and back.shape == (2, 3, 3)
    np.testing.assert_allclose(np.asarray(image).reshape(-1, 2), flat, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back, g, rtol=0, atol=1e-9)


def test_nan_in_nan_out_for_that_point_only(perturbed, truth):
    ground, image = _points(truth, 4, seed=5)
    ground[1, 0] = np.nan
    out = _project(perturbed, ground)
    assert np.all(np.isnan(out[1])) and np.all(np.isfinite(np.delete(out, 1, 0)))
    image[2, 1] = np.nan
    back = _localize(perturbed, image, ground[:, 2])
    assert np.all(np.isnan(back[2, :2])) and np.all(np.isfinite(np.delete(back, 2, 0)))


def test_implicit_root_derivatives_to_second_order():
    """The Newton root's custom JVP for a 2-vector (localize) against finite differences; the
    scalar case (project) is checked to second order in test_gradients."""

    def fun2(x, a):
        return jnp.stack([x[0] ** 3 + a[0] * x[1] - a[1], jnp.sin(x[1]) + a[2] * x[0] - 0.3])

    def root2(a):
        return newton_root(fun2, jnp.array([1.0, 0.2]), a, max_steps=12).value

    a = jnp.array([0.7, 2.0, 0.4])
    np.testing.assert_allclose(fun2(root2(a), a), 0.0, atol=1e-14)
    check_grads(jax.jit(root2), (a,), order=2, modes=("fwd",))
    check_grads(jax.jit(root2), (a,), order=1, modes=("rev",))


@pytest.mark.usefixtures("finite_differences_on_cpu")
def test_gradients(perturbed, truth):
    """check_grads of project w.r.t. ground and the adjustable parameters (eqx.partition)
    jointly, each scaled to ~1 px per unit: order 2 in forward mode, order 1 in reverse mode
    (reverse-over-reverse compiles for minutes and checks the same implicit-derivative rule);
    localize w.r.t. image and h to order 1 (its 2-D root rule is checked to order 2 above)."""
    ground, image = _points(truth, 2, seed=6)
    params, static = eqx.partition(perturbed, perturbed.adjustable_filter())
    scale = eqx.tree_at(
        lambda p: (p.orbit.coeffs, p.attitude.coeffs),
        params,
        (jnp.full_like(params.orbit.coeffs, 2.5), jnp.full_like(params.attitude.coeffs, 3e-6)),
    )
    ground_scale = jnp.array([3e-5, 3e-5, 5.0])  # deg, deg, m

    @jax.jit
    def f(d_ground, d_params):  # the image points and the prior residuals (soft constraints)
        m = eqx.combine(jax.tree.map(lambda p0, s, d: p0 + s * d, params, scale, d_params), static)
        return m.project(ground + ground_scale * d_ground), m.prior_residuals()

    zeros = (jnp.zeros((2, 3)), jax.tree.map(jnp.zeros_like, params))
    check_grads(f, zeros, order=2, modes=("fwd",))
    # f's rounding (~1e-9 px: ECEF metres near 7e6) over check_grads' default step (1e-4) put
    # 1e-5 to 2.5e-5 of relative noise in the reverse check's finite differences (steps of
    # 1e-4 * (1 +- 3e-3), measured; an H200 machine's run failed at 2.0e-5); at 1e-3 they stay
    # under 2.4e-6 over the same steps, the truncation included
    check_grads(f, zeros, order=1, modes=("rev",), eps=1e-3)
    loc = jax.jit(lambda i, h: perturbed.localize(i, h))
    check_grads(loc, (jnp.asarray(image), jnp.asarray(ground[:, 2])), order=1)


def test_prior_residuals(perturbed):
    m = perturbed
    knots = np.asarray(m.orbit.knots())
    orbit = BSpline(knots, np.asarray(m.orbit.coeffs), m.orbit.degree)
    t0, t1 = float(m.orbit.t_start_s), float(m.orbit.t_end_s)
    t = t0 + (np.arange(5) + 0.5) / 5 * (t1 - t0)
    normal = np.cross(orbit(t0), orbit(t1))
    normal /= np.linalg.norm(normal)
    s, v = orbit(t), orbit(t, nu=1)
    expected = np.concatenate(
        [s @ normal / 10.0, (s * v).sum(-1) / np.linalg.norm(s, axis=-1) / 10.0]
    )
    got = np.asarray(m.prior_residuals())
    # S(t_start) x S(t_end) loses ~3 digits (the two are 4 mrad apart): 1e-7 of a sigma
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-7)
    assert np.abs(got).max() > 1.0  # the perturbation is seen
    # switches and direct observations
    assert dataclasses.replace(m, sigma_plane_m=None).prior_residuals().shape == (5,)
    assert dataclasses.replace(m, n_constraint_samples=3).prior_residuals().shape == (6,)
    from_meta = GenericPushbroom.from_metadata(
        _metadata(CartosatTruth()), n_constraint_samples=3, sigma_radial_velocity_m_s=None
    )
    assert from_meta.prior_residuals().shape == (3,)
    off = dataclasses.replace(m, sigma_plane_m=None, sigma_radial_velocity_m_s=None)
    assert off.prior_residuals().shape == (0,)
    att = np.asarray(m.attitude(t[:3]))
    obs = SplineObservations(t[:3], att + [[3e-6, 0.0, -1e-6]], np.array([1e-6, 1e-6, 1e-6]))
    pos = SplineObservations(t[3:], s[3:], 5.0)
    with_obs = eqx.tree_at(
        lambda m: (m.attitude_observations, m.orbit_observations),
        off,
        (obs, pos),
        is_leaf=lambda x: x is None,
    )
    np.testing.assert_allclose(
        with_obs.prior_residuals(), np.r_[np.zeros(6), np.tile([-3.0, 0.0, 1.0], 3)], atol=1e-6
    )


def _levenberg_marquardt(resid, y, steps=60):
    """Small dense LM with Marquardt scaling. The library's adjustment engine is tested
    elsewhere; this one keeps the compile to a single residual-and-Jacobian function."""
    both = jax.jit(lambda y: (resid(y), jax.jacfwd(resid)(y)))
    r, j = (np.asarray(a) for a in both(y))
    lam = 1e-3
    for _ in range(steps):
        a, g = j.T @ j, j.T @ r
        while True:
            dy = np.linalg.solve(a + lam * np.diag(np.diag(a) + 1e-9), -g)
            r_new, j_new = (np.asarray(v) for v in both(y + dy))
            if r_new @ r_new <= r @ r:
                y, r, j, lam = y + dy, r_new, j_new, max(lam / 10, 1e-12)
                break
            lam *= 10
        if np.abs(dy).max() < 1e-8:
            break
    return y


def test_adjustment_to_gcps_reaches_subpixel_at_check_points(truth):
    """The paper's workflow: metadata (with the Hobart metadata's 638 km flying height) ->
    approximate model (offsets up to ~500 px in the paper) -> GCP adjustment of the degree-2
    spline coefficients with the soft constraints -> independent check points. The GCPs are
    exact (no noise) and the model can represent the truth, so the check points must agree."""
    model = GenericPushbroom.from_metadata(_metadata(truth, flying_height_m=638e3), degree=2)
    gcp_ground, gcp_image = _points(truth, 30, seed=8)
    chk_ground, chk_image = _points(truth, 50, seed=9)
    before = np.linalg.norm(_project(model, gcp_ground) - gcp_image, axis=-1)
    params, static = eqx.partition(model, model.adjustable_filter())
    n_orb = params.orbit.coeffs.size
    scale = np.r_[np.full(n_orb, 2.5), np.full(params.attitude.coeffs.size, 3e-6)]  # ~1 px each

    def build(y):
        y = y * scale
        p = eqx.tree_at(
            lambda p: (p.orbit.coeffs, p.attitude.coeffs),
            params,
            (
                params.orbit.coeffs + y[:n_orb].reshape(params.orbit.coeffs.shape),
                params.attitude.coeffs + y[n_orb:].reshape(params.attitude.coeffs.shape),
            ),
        )
        return eqx.combine(p, static)

    def resid(y):
        m = build(y)
        img = (m.project(gcp_ground) - gcp_image) / 0.5  # sigma 0.5 px as in section 4
        return jnp.concatenate([img.ravel(), m.prior_residuals()])

    adjusted = build(_levenberg_marquardt(resid, np.zeros(scale.size)))
    gcp_err = _project(adjusted, gcp_ground) - gcp_image
    chk_err = _project(adjusted, chk_ground) - chk_image
    rms = np.sqrt((chk_err**2).mean(0))
    print(
        f"\ninitial max offset at GCPs {before.max():.1f} px (mean {before.mean():.1f});"
        f" after adjustment: GCP RMS {np.sqrt((gcp_err**2).mean(0))} px,"
        f" check RMS x {rms[0]:.2e} y {rms[1]:.2e} px, max {np.abs(chk_err).max():.2e} px"
    )
    assert 1.0 < before.max() < 500.0
    assert np.all(rms < 0.1)
    assert np.abs(np.asarray(adjusted.prior_residuals())).max() < 1.0


def test_bad_metadata_raises(truth):
    meta = _metadata(truth)
    mirrored = meta.corners[[1, 0, 3, 2]]
    with pytest.raises(ValueError, match="fore.*right of the flight"):
        GenericPushbroom.from_metadata(_metadata(truth, corners=mirrored))
    with pytest.raises(ValueError, match="fore.*flying_height_m"):
        GenericPushbroom.from_metadata(_metadata(truth, flying_height_m=0.0))
    with pytest.raises(ValueError, match="fore.*corners"):
        GenericPushbroom.from_metadata(_metadata(truth, corners=meta.corners[:3]))
    with pytest.raises(ValueError, match="last axis of size 3"):
        unchecked(GenericPushbroom.project)(GenericPushbroom.from_metadata(meta), np.zeros((2, 2)))
