"""The sensor-model interface (every final class implements it) and the shared implicit Newton."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxgeo.models import (
    RPC,
    AbstractMultiImageModel,
    AbstractSensorModel,
    Affine3D,
    AffineBias,
    Biased,
    GenericPushbroom,
    KeplerSequence,
    SceneMetadata,
    ShiftBias,
    ShiftDriftBias,
)
from jaxgeo.models.internal import gmst_rad, newton_root
from jaxgeo.simulate import CircularOrbit, EphemerisSettings, ephemeris_from_orbit
from jaxgeo.simulate._orbit import sun_synchronous_inclination_deg

LON, LAT = 147.30, -42.88


def _rpc() -> RPC:
    num = np.zeros((2, 20))
    den = np.zeros((2, 20))
    num[0, 1], num[1, 2] = 1.0, -1.0  # x ~ lon, y ~ -lat
    num[0, 3], num[1, 3] = 0.01, 0.02
    den[:, 0] = 1.0
    return RPC(num, den, [LON, LAT, 500.0], [0.05, 0.05, 500.0], [5000.0, 5000.0], [5000.0] * 2)


def _scene() -> SceneMetadata:
    d = 0.05
    corners = [
        [LON - d, LAT + d, 0.0],
        [LON + d, LAT + d, 0.0],
        [LON + d, LAT - d, 0.0],
        [LON - d, LAT - d, 0.0],
    ]
    return SceneMetadata("s", 12000, 12000, corners, 618e3, 0.0, 0.0, 1945.0, 7.0, 0.336e-3)


def _ephemeris():
    theta0 = gmst_rad("2006-10-01T00:40:00Z")
    orbit = CircularOrbit.over(LON, LAT, 618e3, sun_synchronous_inclination_deg(618e3), theta0)
    return ephemeris_from_orbit(
        orbit,
        (-3.0, 3.0),
        EphemerisSettings(
            sidereal_angle_rad=theta0,
            line_time_s=0.336e-3,
            n_rows=12000,
            n_cols=12000,
            focal_length_m=1.945,
            pixel_size_m=7e-6,
        ),
        first_line_time_s=-2.0,
    )


def _models() -> dict[str, AbstractSensorModel]:
    rpc = _rpc()
    ijk = [(0, 0, 0), (1, 0, 1), (0, 1, 2), (1, 1, 0), (2, 1, 1), (1, 2, 3)]
    ground = np.array([[LON + 0.01 * i, LAT - 0.01 * j, 100.0 * k] for i, j, k in ijk])
    seq = KeplerSequence.from_metadata([_scene()])
    return {
        "rpc": rpc,
        "biased_shift": Biased(rpc, ShiftBias((0.5, -1.0))),
        "biased_drift": Biased(rpc, ShiftDriftBias((0.5, -1.0), (1e-5, 0.0))),
        "biased_affine": Biased(rpc, AffineBias((0.5, -1.0), ((1e-5, 0.0), (0.0, 2e-5)))),
        "affine3d": Affine3D.fit(ground, np.asarray(rpc.project(ground)), space="geographic"),
        "pushbroom": GenericPushbroom.from_metadata(_scene()),
        "ephemeris": _ephemeris(),
        "kepler_image": seq.image(0),
    }


MODELS = _models()
EXPECTED_GCPS = {
    "biased_shift": (1, "the ShiftBias (2 parameters)"),
    "biased_drift": (2, "the ShiftDriftBias (4 parameters)"),
    "biased_affine": (3, "the AffineBias (6 parameters)"),
    "affine3d": (4, "the 3D affine model (8 parameters, non-coplanar GCPs)"),
}


@pytest.mark.parametrize("name", sorted(MODELS))
def test_every_sensor_model_implements_the_interface(name):
    model = MODELS[name]
    spec = model.adjustable_filter()
    dynamic, static = eqx.partition(model, spec)
    assert jax.tree.structure(eqx.combine(dynamic, static)) == jax.tree.structure(model)
    adjusted = jax.tree.leaves(dynamic)
    assert all(eqx.is_inexact_array(x) for x in adjusted)
    assert (len(adjusted) > 0) == (name != "rpc")
    assert model.required_gcps(dynamic) == EXPECTED_GCPS.get(name)
    # nothing adjusted: no GCPs needed
    frozen, _ = eqx.partition(model, False)
    assert model.required_gcps(frozen) is None
    assert model.prior_residuals().ndim == 1
    if name != "pushbroom":
        assert model.prior_residuals().shape == (0,)
    exact = model.exact_rpc()
    if name in ("rpc", "biased_shift"):
        assert isinstance(exact, RPC)
        g = np.array([[LON + 0.01, LAT - 0.02, 300.0], [LON - 0.03, LAT + 0.01, 800.0]])
        np.testing.assert_allclose(exact.project(g), model.project(g), rtol=0, atol=1e-9)
    else:
        assert exact is None


def test_biased_rpc_filter_is_the_bias_only():
    model = MODELS["biased_drift"]
    dynamic, _ = eqx.partition(model, model.adjustable_filter())
    assert jax.tree.leaves(dynamic.model) == []
    assert len(jax.tree.leaves(dynamic.bias)) == 2


def test_a_zero_drift_folds_exactly_into_the_rpc():
    rpc = MODELS["rpc"]
    exact = Biased(rpc, ShiftDriftBias((0.5, -1.0), (0.0, 0.0))).exact_rpc()
    np.testing.assert_allclose(exact.image_offset, np.asarray(rpc.image_offset) - [0.5, -1.0])


def test_kepler_sequence_is_a_multi_image_model():
    seq = KeplerSequence.from_metadata([_scene(), _scene()])
    assert isinstance(seq, AbstractMultiImageModel)
    assert seq.n_images == 2 and isinstance(seq.image(1), AbstractSensorModel)
    dynamic, _ = eqx.partition(seq, seq.adjustable_filter())
    assert len(jax.tree.leaves(dynamic)) == 4  # position, velocity, two attitude vectors
    assert seq.required_gcps(dynamic) is None
    assert seq.prior_residuals().shape == (0,)


# --- the shared Newton ------------------------------------------------------------------


def _cubic(x, a):
    return x**3 - a


def test_newton_flags_each_solve_and_isolates_nan():
    a = jnp.array([8.0, jnp.nan, 27.0])

    def solve(a):
        return jax.vmap(lambda ai: newton_root(_cubic, 1.0, ai, max_steps=50, tol=1e-14))(a)

    sol = solve(a)
    np.testing.assert_allclose(sol.value[np.array([0, 2])], [2.0, 3.0], rtol=1e-15)
    assert np.asarray(sol.converged).tolist() == [True, False, True]
    assert np.isnan(sol.value[1])
    # too few steps: not converged, and said so
    few = jax.vmap(lambda ai: newton_root(_cubic, 1.0, ai, max_steps=2, tol=1e-14))(a)
    assert not np.any(np.asarray(few.converged))
    # the NaN point poisons neither the others' values nor their gradients
    grad = jax.grad(lambda a: jnp.nansum(solve(a).value))(a)
    np.testing.assert_allclose(grad[np.array([0, 2])], [1 / 12, 1 / 27], rtol=1e-12)
    assert grad[1] == 0.0


def test_newton_implicit_derivatives():
    def root(a):
        return newton_root(_cubic, 1.0, a, max_steps=60, tol=1e-15).value

    check_grads(root, (jnp.array(5.0),), order=2, modes=("fwd", "rev"))


def _linear3(x, args):
    m, b = args
    return m @ x + 0.1 * jnp.sin(x) - b


def test_newton_three_unknowns_written_out_solve():
    """3 x 3 Newton systems are solved in closed form (no LAPACK call per point): the same roots
    and implicit derivatives as ``jnp.linalg.solve``'s, and a singular system isolated."""
    from jaxgeo.models._newton import _det, _solve

    rng = np.random.default_rng(3)
    ms = rng.normal(size=(50, 3, 3)) + 2 * np.eye(3)
    bs = rng.normal(size=(50, 3))
    np.testing.assert_allclose(
        jax.vmap(_solve)(ms, bs), np.linalg.solve(ms, bs[..., None])[..., 0], rtol=1e-10
    )
    np.testing.assert_allclose(jax.vmap(_det)(ms), np.linalg.det(ms), rtol=1e-12)
    m, b = jnp.asarray(ms[0]), jnp.asarray(bs[0])

    def root(m, b):
        return newton_root(_linear3, jnp.zeros(3), (m, b), max_steps=30, tol=1e-14).value

    x = root(m, b)
    np.testing.assert_allclose(_linear3(x, (m, b)), 0.0, atol=1e-12)
    check_grads(root, (m, b), order=1, modes=("fwd", "rev"))
    singular = -0.1 * jnp.eye(3)  # the Jacobian m + 0.1 cos(x) is zero at the start
    sol = newton_root(_linear3, jnp.zeros(3), (singular, b), max_steps=5, tol=1e-14)
    assert not bool(sol.converged)
    grad = jax.grad(lambda b: jnp.nansum(root(singular, b)))(b)
    assert np.all(np.isfinite(grad))


def test_localize_gradient_through_the_shared_newton_and_nan_isolation():
    """The RPC has no direct localisation: base localize runs the shared Newton."""
    rpc = MODELS["rpc"]
    image = jnp.array([[4000.0, 5200.0], [jnp.nan, 10.0], [6100.0, 4500.0]])
    h = jnp.array([100.0, 200.0, 700.0])
    back = rpc.localize(image, h)
    assert np.all(np.isnan(back[1])) and np.all(np.isfinite(back[np.array([0, 2])]))
    ok = np.array([0, 2])
    # 1e5 px per degree: one ulp of lon = 147 deg is 3e-9 px
    np.testing.assert_allclose(rpc.project(back[ok]), image[ok], rtol=0, atol=1e-8)

    def f(image_offset, h):
        model = eqx.tree_at(lambda m: m.image_offset, rpc, image_offset)
        return model.localize(image[jnp.array([0, 2])], h[jnp.array([0, 2])])

    check_grads(f, (rpc.image_offset, h), order=1, modes=("fwd", "rev"), eps=1e-3)
    g = jax.grad(lambda off: jnp.nansum(eqx.tree_at(lambda m: m.image_offset, rpc, off)
                                        .localize(image, h)))(rpc.image_offset)  # fmt: skip
    assert np.all(np.isfinite(g))
