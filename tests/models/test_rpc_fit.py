"""Terrain-independent RPC fitting (fit_rpc) against the rigorous model it is fitted to."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo.models import (
    AbstractSensorModel,
    EphemerisModel,
    fit_rpc,
    fit_rpcs,
    localize_points,
    project_points,
)
from jaxgeo.models.internal import gmst_rad
from jaxgeo.simulate import CircularOrbit, EphemerisSettings, ephemeris_from_orbit
from jaxgeo.simulate._orbit import sun_synchronous_inclination_deg

N = 12000
H_RANGE = (-100.0, 1400.0)


def cartosat1_camera(view_deg: float, t_centre: float) -> EphemerisModel:
    """A real-size Cartosat-1 camera (618 km, f 1945 mm, 7 um, 12000 x 12000, 0.336 ms)."""
    theta0 = gmst_rad("2006-10-01T00:40:00Z")
    orbit = CircularOrbit.over(147.3, -42.88, 618e3, sun_synchronous_inclination_deg(618e3), theta0)
    wobble = np.array([[3e-6, -2e-6, 1e-6, 5e-7], [-4e-6, 1e-6, 0.0, 0.0], [2e-6, 0.0, 1e-6, 0.0]])
    return ephemeris_from_orbit(
        orbit, (-80.0, 40.0), EphemerisSettings(sidereal_angle_rad=theta0, line_time_s=0.336e-3,
        n_rows=N, n_cols=N, focal_length_m=1.945, pixel_size_m=7e-6),
        first_line_time_s=t_centre - (N - 1) / 2 * 0.336e-3, view_angles_deg=(view_deg, 0.0, 0.0),
        attitude_offsets_rad=wobble,
    )  # fmt: skip


@pytest.fixture(scope="module")
def cameras():
    return {"fore": cartosat1_camera(26.0, -44.6), "aft": cartosat1_camera(-5.0, 7.9)}


@pytest.fixture(scope="module")
def fitted(cameras):
    return dict(zip(cameras, fit_rpcs(list(cameras.values()), h_range=H_RANGE), strict=False))


def random_points(model, n, seed, n_cols=N, n_rows=N, h_range=H_RANGE):
    """Independent points: random image positions and heights, localised by the model."""
    rng = np.random.default_rng(seed)
    image = rng.uniform(0, 1, (n, 2)) * [n_cols - 1, n_rows - 1]
    h = rng.uniform(*h_range, n)
    return localize_points(model, image, h), image


def test_fit_accuracy_on_independent_points(cameras, fitted):
    # target of the issue: < 0.01 px RMS and < 0.05 px max on independent check points
    for name, model in cameras.items():
        rpc, report = fitted[name]
        assert report.n_fit == 21 * 21 * 7 and report.n_check == 20 * 20 * 6
        ground, image = random_points(model, 3000, seed=1)
        err = np.linalg.norm(project_points(rpc, ground) - image, axis=-1)
        rms, worst = float(np.sqrt(np.mean(err**2))), float(err.max())
        print(
            f"{name}: fit grid rms {report.fit_rms_px:.2e} max {report.fit_max_px:.2e} px; "
            f"check grid rms {report.check_rms_px:.2e} max {report.check_max_px:.2e} px; "
            f"random points rms {rms:.2e} max {worst:.2e} px"
        )
        assert report.check_rms_px < 0.01 and report.check_max_px < 0.05
        assert report.fit_rms_px < 0.01 and report.fit_max_px < 0.05
        assert rms < 0.01 and worst < 0.05
        # normalisation from the grid: image centre, full cube
        assert np.allclose(rpc.image_offset, [5999.5, 5999.5])
        assert np.allclose(rpc.ground_offset[2], 650.0) and np.allclose(rpc.ground_scale[2], 750.0)
        assert bool(np.all(rpc.in_domain(ground, margin=1e-9)))


def test_both_term_orders_give_the_same_rpc(cameras, fitted):
    rpc_b = fitted["fore"][0]
    rpc_a, report_a = fit_rpc(cameras["fore"], h_range=H_RANGE, order="RPC00A")
    ground, _ = random_points(cameras["fore"], 500, seed=2)
    assert np.abs(project_points(rpc_a, ground) - project_points(rpc_b, ground)).max() < 1e-5
    assert report_a.check_rms_px < 0.01
    # the RPC00A solve really ran in that order: its constant-free denominator terms are not the
    # RPC00B solution's (the fit is not unique along near-null directions; the map is)
    assert not np.array_equal(np.asarray(rpc_a.den), np.asarray(rpc_b.den))


def test_batch_equals_single_fits(cameras, fitted):
    rpc, report = fit_rpc(cameras["aft"], h_range=H_RANGE)
    assert np.array_equal(np.asarray(rpc.num), np.asarray(fitted["aft"][0].num))
    assert report == fitted["aft"][1]


def test_refits_a_real_pleiades_rpc(pleiades):
    """Any model: an RPC fitted to a real vendor RPC (generic Newton localize) is that RPC."""
    real, _ = pleiades
    n_cols, n_rows = (int(round(2 * o + 1)) for o in np.asarray(real.image_offset))
    h_range = (200.0, 1200.0)
    rpc, report = fit_rpc(real, n_cols, n_rows, h_range, grid=(11, 11, 5))
    ground, image = random_points(real, 400, 3, n_cols, n_rows, h_range)
    err = np.abs(project_points(rpc, ground) - image).max()
    print(
        f"Pleiades refit: check grid max {report.check_max_px:.1e} px, "
        f"random points max {err:.1e} px"
    )
    assert report.check_max_px < 0.01 and err < 0.01


class _Nowhere(AbstractSensorModel):
    """A model that cannot localise anything (its rays miss the Earth)."""

    def project(self, ground):
        return jnp.zeros(jnp.shape(ground)[:-1] + (2,))

    def reference_ground(self):
        return jnp.zeros(3)

    def adjustable_filter(self):
        return False

    def required_gcps(self, dynamic):
        return None

    def localize(self, image, h, guess=None):
        shape = jnp.broadcast_shapes(jnp.shape(image)[:-1], jnp.shape(h))
        return jnp.full((*shape, 3), jnp.nan)


def test_bad_input(cameras):
    with pytest.raises(ValueError, match="h_range must be increasing"):
        fit_rpc(cameras["fore"], h_range=(100.0, 100.0))
    with pytest.raises(ValueError, match="at least 4 points"):
        fit_rpc(cameras["fore"], grid=(3, 10, 10))
    with pytest.raises(ValueError, match="term order"):
        fit_rpc(cameras["fore"], order="RPC00C")
    with pytest.raises(ValueError, match="could not localise"):
        fit_rpc(_Nowhere(), 100, 100, (0.0, 10.0), grid=(4, 4, 4))


def test_refit_through_exported_programs_equals_the_jitted_one(cameras, monkeypatch, tmp_path):
    """The CLI's path (the refit's localisation, fit and check projections as serialized
    ``jax.export`` programs, ``jaxgeo._runtime.exported``): the suite's plain-jit RPC to
    rounding, and a new process (the programs loaded from disk) exports, so traces, nothing
    again."""
    from jaxgeo._runtime import exported as _exported

    want = fit_rpc(cameras["aft"], h_range=H_RANGE, grid=(6, 6, 4))
    exported = []
    real_export = _exported._export
    monkeypatch.setattr(
        _exported, "_export", lambda fn, *a: exported.append(fn.__name__) or real_export(fn, *a)
    )
    monkeypatch.setenv("JAXGEO_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_exported, "_loaded", {})
    got = fit_rpc(cameras["aft"], h_range=H_RANGE, grid=(6, 6, 4))
    names = ("_localize_chunk", "_fit_normalized", "_project_rpc")
    # one localisation program (fixed chunks), one fit, a projection per grid (fit, check)
    assert sorted(exported) == sorted([*names, "_project_rpc"])
    _exported._loaded.clear()  # as a new process
    again = fit_rpc(cameras["aft"], h_range=H_RANGE, grid=(6, 6, 4))
    assert len(exported) == 4  # nothing traced again
    ground, image = random_points(cameras["aft"], 200, seed=4)
    for rpc, report in (got, again):
        # the suite compiles with other XLA options (tests/conftest.py): equal to rounding, the
        # refit's own floor (~1e-6 px): 1.03e-6 px on an AVX-512 CPU, < 1e-6 without
        err = np.abs(project_points(rpc, ground) - project_points(want[0], ground)).max()
        assert err < 2e-6, err
        # the grid's errors are ~1e-6 px, at the roundings' floor
        assert report.check_max_px == pytest.approx(want[1].check_max_px, abs=1e-5)
        assert report.n_fit == want[1].n_fit == 6 * 6 * 4


def test_many_points_in_large_chunks_compiled_for_speed(fitted, monkeypatch, tmp_path):
    """``localize_points`` / ``project_points``: below ``CHUNKS[1]`` points in small chunks,
    from there on in large ones compiled with XLA's defaults (``_exported.call_kernel``, not the
    slow-running quick options); any number of points from the same two programs, the model's
    own results either way."""
    from jaxgeo._runtime import exported as _exported
    from jaxgeo.models import _rpc_fit

    monkeypatch.setenv("JAXGEO_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_exported, "_loaded", {})
    monkeypatch.setattr(_exported, "_runners", {})
    kernels = []
    real_kernel = _exported.call_kernel
    monkeypatch.setattr(
        _exported, "call_kernel", lambda fn, *a: kernels.append(len(a[1])) or real_kernel(fn, *a)
    )
    rpc = fitted["fore"][0]
    small, large = _rpc_fit.CHUNKS
    rng = np.random.default_rng(5)
    assert localize_points(rpc, np.zeros((0, 2)), 0.0).shape == (0, 3)
    assert project_points(rpc, np.zeros((4, 0, 3))).shape == (4, 0, 2)
    for n in (3, small + 1, large - 1, large, 2 * large + 7):
        image = rng.uniform(0, N - 1, (n, 2))
        h = rng.uniform(*H_RANGE, n)
        ground = localize_points(rpc, image, h)
        assert ground.shape == (n, 3)
        np.testing.assert_allclose(project_points(rpc, ground), image, atol=1e-6)
        want = np.asarray(rpc.project(jnp.asarray(ground)))
        np.testing.assert_allclose(project_points(rpc, ground[None]), want[None], atol=1e-9)
    # localised once and projected twice: large points in 1 chunk, 2 * large + 7 in 3
    assert kernels == [large] * (3 * 1 + 3 * 3)
    # two programs per function: the small chunk and the large one
    assert len(_exported._runners) == 4
