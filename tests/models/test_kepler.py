"""UCL Kepler along-track model: against an independent pinhole-along-a-circular-orbit generator.

The generator below shares only physics with jaxgeo (a circular two-body orbit, Earth rotation
about z, a nadir-tracking yaw-steered platform with small roll/pitch/yaw offsets and rates, a
pinhole line camera tilted by the view angle); it is written in numpy, uses pyproj for geodesy
and goes the other way (image -> ground by intersecting rays with the height surface).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pyproj
import pytest
import scipy.integrate
from jax.test_util import check_grads

from jaxgeo.models import KeplerSequence, SceneMetadata
from jaxgeo.models._kepler import (
    KeplerImage,
    propagate,
    propagate_taylor2,
    taylor_coefficients,
    taylor_state,
)

GM = 398600.4415e9
OMEGA_E = 7.2921151467e-5
N_PX = 12000
LAST = N_PX - 1.0
CORNERS_PX = np.array([[0.0, 0.0], [LAST, 0.0], [LAST, LAST], [0.0, LAST]])
_TO_GEO = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
_TO_ECEF = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


class Truth:
    """Cartosat-1-like stereo pair: 618 km above the scene, f = 1945 mm, 7 um, 0.336 ms lines,
    fore +26 deg / aft -5 deg, aft 52.9 s after fore (then both see the same ground)."""

    def __init__(self, alphas=(26.0, -5.0), t0s=(0.0, 52.92), seed=0):
        lat, lon, incl = 52.2, 21.0, np.deg2rad(97.9)  # Warsaw, descending sun-synchronous
        u = np.pi - np.arcsin(np.sin(np.deg2rad(lat + 2.9)) / np.sin(incl))
        raan = np.deg2rad(lon) - np.arctan2(np.cos(incl) * np.sin(u), np.cos(u))
        self.p = np.array([np.cos(raan), np.sin(raan), 0.0])
        self.q = np.array([-np.cos(incl) * np.sin(raan), np.cos(incl) * np.cos(raan), np.sin(incl)])
        self.u0 = u
        self.rs = np.linalg.norm(_TO_ECEF.transform(lon, lat, 0.0)) + 618e3
        self.n = np.sqrt(GM / self.rs**3)
        self.f_px, self.lt = 1945.0 * 1e3 / 7.0, 0.336e-3  # as KeplerCamera.from_metadata
        self.alphas, self.t0s = alphas, t0s
        rng = np.random.default_rng(seed)  # (omega, phi, kappa) offsets (rad), rates (rad/s)
        self.att = [np.r_[rng.normal(0, 50e-6, 3), rng.normal(0, 3e-6, 3)] for _ in alphas]
        self.steer = [self._steering(self.tc(k)) for k in range(len(alphas))]

    def tc(self, k):
        return self.t0s[k] + 0.5 * LAST * self.lt

    def state(self, tau):
        u = self.u0 + self.n * tau
        r = self.rs * (np.cos(u) * self.p + np.sin(u) * self.q)
        return r, self.rs * self.n * (-np.sin(u) * self.p + np.cos(u) * self.q)

    def frame(self, tau):
        r, v = self.state(tau)
        z, x = r / np.linalg.norm(r), v / np.linalg.norm(v)
        return np.stack([x, np.cross(z, x), z], axis=1)

    def _steering(self, tau):  # yaw that aligns the platform with the ground-relative velocity
        r, v = self.state(tau)
        rel = v - np.cross([0.0, 0.0, OMEGA_E], r)
        x, _, z = self.frame(tau).T
        return np.arctan2(np.cross(x, rel) @ z, x @ rel)

    def rot(self, k, tau):
        a, dt = self.att[k], tau - self.tc(k)
        mount = _ry(-np.deg2rad(self.alphas[k]))
        return (
            self.frame(tau)
            @ _rx(a[0] + a[3] * dt)
            @ _ry(a[1] + a[4] * dt)
            @ _rz(self.steer[k] + a[2] + a[5] * dt)
            @ mount
        )

    def localize(self, k, px, h):
        """(n, 2) pixels at heights (n,) -> (n, 3) lon, lat, h (ray / height-surface)."""
        px, h = np.atleast_2d(px), np.broadcast_to(h, (len(np.atleast_2d(px)),))
        out = []
        for (col, row), hk in zip(px, h, strict=True):
            tau = self.t0s[k] + row * self.lt
            d = self.rot(k, tau) @ [0.0, (col - 0.5 * LAST) / self.f_px, -1.0]
            r = _rz(-OMEGA_E * tau) @ self.state(tau)[0]
            d = _rz(-OMEGA_E * tau) @ d / np.linalg.norm(d)
            lam = -(r @ d) - np.sqrt((r @ d) ** 2 - r @ r + (6378137.0 + hk) ** 2)
            for _ in range(8):  # Newton on the ellipsoidal height along the ray
                lon, lat, hh = _TO_GEO.transform(*(r + lam * d))
                lo, la = np.deg2rad(lon), np.deg2rad(lat)
                up = [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]
                lam -= (hh - hk) / (d @ up)
            out.append(_TO_GEO.transform(*(r + lam * d)))
        return np.array(out)

    def project(self, k, ground):
        """(n, 3) lon, lat, h -> (n, 2) pixels (secant iteration on the exposure time)."""
        out = []
        for g in np.atleast_2d(ground):
            g = np.array(_TO_ECEF.transform(*g))

            def ray(tau, g=g):
                return self.rot(k, tau).T @ (_rz(OMEGA_E * tau) @ g - self.state(tau)[0])

            t1, t2 = self.tc(k), self.tc(k) + 0.01
            f1, f2 = ray(t1)[0] / -ray(t1)[2], ray(t2)[0] / -ray(t2)[2]
            for _ in range(30):
                if f2 == f1:
                    break
                t1, t2, f1 = t2, t2 - f2 * (t2 - t1) / (f2 - f1), f2
                f2 = ray(t2)[0] / -ray(t2)[2]
            d = ray(t2)
            out.append([0.5 * LAST + self.f_px * d[1] / -d[2], (t2 - self.t0s[k]) / self.lt])
        return np.array(out)

    def metadata(self):
        return [
            SceneMetadata(
                f"img{k}",
                N_PX,
                N_PX,
                self.localize(k, CORNERS_PX, 0.0),
                618e3,
                self.alphas[k],
                0.0,
                1945.0,
                7.0,
                self.lt,
                self.t0s[k],
            )
            for k in range(len(self.alphas))
        ]

    def sequence(self, start):
        """The jaxgeo model that represents this truth exactly: ``start`` (a sequence from
        this truth's metadata, orders (1, 1, 1)) with the true orbit and attitude."""
        att = [np.r_[a[:2], a[2] + s, a[3:]] for a, s in zip(self.att, self.steer, strict=True)]
        r0, v0 = self.state(0.0)
        return eqx.tree_at(
            lambda q: (q.position_m, q.velocity_m_s, q.attitude),
            start,
            (jnp.asarray(r0), jnp.asarray(v0), tuple(jnp.asarray(a) for a in att)),
        )


@pytest.fixture(scope="module")
def truth():
    return Truth()


@pytest.fixture(scope="module")
def start(truth):
    """Initial values from the truth's metadata (the sequence the fit starts from)."""
    return KeplerSequence.from_metadata(truth.metadata(), orders=(1, 1, 1))


@pytest.fixture(scope="module")
def exact(truth, start):
    return truth.sequence(start)  # same static cameras as ``start``: compiled code is shared


@pytest.fixture(scope="module")
def points(truth):
    """40 ground points seen by both images: (40, 3) ground, (2, 40, 2) pixels."""
    rng = np.random.default_rng(1)
    px = rng.uniform(0.0, LAST, (70, 2))
    ground = truth.localize(0, px, rng.uniform(0.0, 500.0, 70))
    aft = truth.project(1, ground)
    inside = np.flatnonzero(np.all((aft >= 0) & (aft <= LAST), axis=1))[:40]
    assert len(inside) == 40
    return ground[inside], np.stack([px[inside], aft[inside]])


# every point set below has 20 points, so each image compiles project / localize once
_project = eqx.filter_jit(lambda seq, k, g: seq.project(k, g))
_localize = eqx.filter_jit(lambda seq, k, x, h: seq.localize(k, x, h))


def test_propagate_matches_numerical_two_body():
    r0, v0 = np.array([-4.5e6, 2.8e6, -4.5e6]), np.array([4613.7, -1670.0, -5742.8])

    def rhs(_, y):
        return np.r_[y[3:], -GM * y[:3] / np.linalg.norm(y[:3]) ** 3]

    for dt in (-60.0, 52.0, 1500.0):
        ref = scipy.integrate.solve_ivp(rhs, (0.0, dt), np.r_[r0, v0], method="DOP853",
                                        rtol=1e-13, atol=1e-9).y[:, -1]  # fmt: skip
        r, v = propagate(r0, v0, dt)
        assert np.abs(np.asarray(r) - ref[:3]).max() < 1e-3, dt  # mm over 60 s and 25 min
        assert np.abs(np.asarray(v) - ref[3:]).max() < 1e-6, dt
        if abs(dt) < 100.0:  # the per-image Taylor series, from the epoch here
            rt, vt = taylor_state(taylor_coefficients(r0, v0), dt)
            assert np.abs(np.asarray(rt) - ref[:3]).max() < 1e-3
            assert np.abs(np.asarray(vt) - ref[3:]).max() < 1e-6
    # the paper's second-order series departs by hundreds of metres over the fore/aft interval
    r2, _ = propagate_taylor2(r0, v0, 52.0)
    r, _ = propagate(r0, v0, 52.0)
    assert 50.0 < np.linalg.norm(np.asarray(r2 - r)) < 1000.0


def test_project_matches_independent_generator(exact, points):
    ground, px = points
    for k in range(2):
        for part in (slice(0, 20), slice(20, 40)):
            err = np.asarray(_project(exact, k, ground[part])) - px[k, part]
            assert np.abs(err).max() < 1e-6, (k, np.abs(err).max())


def test_round_trip_over_the_scene(exact):
    grid = np.stack(np.meshgrid(np.linspace(0, LAST, 5), np.linspace(0, LAST, 4)), -1)
    grid = grid.reshape(20, 2)  # includes the four corners
    h = np.random.default_rng(2).uniform(-50.0, 1500.0, 20)
    for k in range(2):
        ground = _localize(exact, k, grid, h)
        assert np.abs(np.asarray(ground[:, 2]) - h).max() < 1e-9
        again = _project(exact, k, ground)
        assert np.abs(np.asarray(again) - grid).max() < 1e-6
        back = _localize(exact, k, again, h)
        assert np.abs(np.asarray(back - ground)[:, :2]).max() < 1e-10  # deg (1e-5 m)


@pytest.mark.parametrize("shape", [(), (5,), (2, 3)])
def test_batch_shapes(exact, shape):
    rng = np.random.default_rng(3)
    image = exact.image(1)
    localize, project = eqx.filter_jit(image.localize), eqx.filter_jit(image.project)
    px = rng.uniform(0.0, LAST, (*shape, 2))
    h = rng.uniform(0.0, 300.0, shape)
    ground = localize(px, h)
    assert ground.shape == (*shape, 3)
    out = project(ground)
    assert out.shape == (*shape, 2)
    np.testing.assert_allclose(np.asarray(out), px, atol=1e-6)
    if shape == ():  # bad points come back as NaN
        assert np.isnan(np.asarray(localize(jnp.array([np.nan, 5.0]), 0.0))).all()
        assert np.isnan(np.asarray(localize(jnp.array([1e7, 5.0]), 0.0))).all()  # misses Earth
        assert np.isnan(np.asarray(project(jnp.array([np.nan, 52.0, 0.0])))).all()


def test_gradients(exact, points):
    """check_grads of project w.r.t. ground and parameters together (a random direction in
    both), orders 1 and 2 forward, 1 reverse; of localize w.r.t. the image, order 1."""
    ground = jnp.asarray(points[0][:2])
    params, static = eqx.partition(exact, eqx.is_inexact_array)

    @jax.jit
    def project(g, p):  # eps 1e-6: the attitude rates change the line rate, strongly nonlinear
        return eqx.combine(p, static).project(1, g)

    check_grads(project, (ground, params), order=2, modes=("fwd",), eps=1e-6, rtol=1e-5)
    check_grads(project, (ground, params), order=1, modes=("rev",), eps=1e-6, rtol=1e-5)

    @jax.jit
    def localize_m(px):  # lon/lat scaled to ~metres so the tolerance means something
        return exact.localize(0, px, jnp.array([10.0, 250.0]))[..., :2] * 1e5

    px = jnp.asarray(points[1][0][:2])
    check_grads(localize_m, (px,), order=1, modes=("fwd", "rev"), rtol=1e-5, atol=1e-6)


def test_from_metadata_and_fit_recovers_truth(truth, start, points):
    ground, px = points
    corner_err = 0.0
    for k, scene in enumerate(truth.metadata()):  # corners + 16 points: the 20-point compile
        g = np.concatenate([scene.corners, ground[:16]])
        x = np.concatenate([CORNERS_PX, px[k, :16]])
        corner_err = max(corner_err, np.abs(np.asarray(_project(start, k, g)) - x).max())
    print(f"initial values from metadata: max error {corner_err:.1f} px")
    assert corner_err < 400.0

    gcp, chk = slice(0, 20), slice(20, 40)
    params0, static = eqx.partition(start, eqx.is_inexact_array)
    units = eqx.tree_at(  # steps in m, mm/s, urad, urad/s: all O(0.1-1 px)
        lambda p: (p.position_m, p.velocity_m_s, p.attitude),
        params0,
        (jnp.ones(3), jnp.full(3, 1e-3), tuple(jnp.full_like(a, 1e-6) for a in params0.attitude)),
    )

    def model(y):
        return eqx.combine(jax.tree.map(lambda p, u, d: p + u * d, params0, units, y), static)

    def residuals(y, args):
        g, im = args
        return jnp.stack([model(y).project(k, g) - im[k] for k in range(2)])

    y0 = jax.tree.map(jnp.zeros_like, params0)
    sol = optx.least_squares(
        residuals,
        optx.GaussNewton(rtol=1e-6, atol=1e-6),  # 1e-6 of the units above
        y0,
        args=(jnp.asarray(ground[gcp]), jnp.asarray(px[:, gcp])),
        max_steps=20,
        throw=False,
    )
    assert sol.result == optx.RESULTS.successful
    print(f"Gauss-Newton from the metadata: {int(sol.stats['num_steps'])} steps")
    fit = model(sol.value)
    res = np.stack([np.asarray(_project(fit, k, ground[chk])) - px[k, chk] for k in range(2)])
    rms = np.sqrt((res**2).mean())
    print(f"20 GCPs, 20 check points x 2 images: rms {rms:.2e} px, max {np.abs(res).max():.2e} px")
    assert rms < 0.1
    assert isinstance(fit.image(0), KeplerImage)


def test_rotation_orders_of_table_7(exact):
    # table 7 of 002_: (w0,p0,k0), (w0,p1,k0), (w1,p1,k0), (w1,p1,k1) for a pair: 12..18 params
    for orders, n in (((0, 0, 0), 12), ((0, 1, 0), 14), ((1, 1, 0), 16), ((1, 1, 1), 18)):
        seq = exact.with_orders([orders, orders])
        assert seq.n_params == n
        params = eqx.filter(seq, eqx.is_inexact_array)
        assert sum(x.size for x in jax.tree.leaves(params)) == n
    mixed = exact.with_orders([(0, 1, 0), (1, 0, 1)])
    cam = exact.cameras[1]
    a = np.asarray(mixed.attitude[1])
    got = np.asarray(mixed.angles(1, cam.centre_time_s + 2.0))
    np.testing.assert_allclose(got, [a[0] + 2 * a[3], a[1], a[2] + 2 * a[4]], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(exact.attitude[1])[[3, 5]], a[3:], rtol=1e-12)


def test_errors(truth, exact):
    scene = truth.metadata()[0]
    bare = SceneMetadata("bare", N_PX, N_PX, scene.corners, 618e3, 26.0)
    with pytest.raises(ValueError, match="focal_length_mm, pixel_size_um, line_time_s"):
        KeplerSequence.from_metadata([bare])
    with pytest.raises(ValueError, match="three of 0 or 1"):
        exact.with_orders([(0, 2, 0), (0, 0, 0)])
    with pytest.raises(ValueError, match="must have 4 coefficients"):
        KeplerSequence(exact.position_m, exact.velocity_m_s, [jnp.zeros(3)] * 2, exact.cameras,
                       [(1, 0, 0)] * 2)  # fmt: skip
    with pytest.raises(ValueError, match="unknown propagator"):
        KeplerSequence(exact.position_m, exact.velocity_m_s, exact.attitude, exact.cameras,
                       exact.orders, "rk4")  # fmt: skip
