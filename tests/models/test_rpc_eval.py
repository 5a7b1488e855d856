"""The numpy-in/numpy-out paths of ``jaxgeo.models._rpc_eval``: chunking, padding buckets and
asynchronous collection give the same numbers as one traced call."""

import jax
import numpy as np
import pytest

from jaxgeo.models import _rpc_eval as rpc_eval


@pytest.mark.parametrize("n", [1, 17, 100, 1000])
def test_chunked_paths_equal_one_traced_call(pleiades, monkeypatch, n):
    rpc, _ = pleiades
    monkeypatch.setattr(rpc_eval, "CHUNK", 64)  # many chunks, the last one padded
    monkeypatch.setattr(rpc_eval, "IN_FLIGHT", 3)
    rng = np.random.default_rng(n)
    go, gs = np.asarray(rpc.ground_offset), np.asarray(rpc.ground_scale)
    ground = go + gs * rng.uniform(-0.9, 0.9, (n, 3))
    xy = rpc.project(ground)
    assert isinstance(xy, np.ndarray) and xy.shape == (n, 2)
    traced = np.asarray(jax.jit(lambda r, g: r.project(g))(rpc, ground))
    np.testing.assert_allclose(xy, traced, rtol=0, atol=1e-9)
    back = rpc.localize(xy, ground[:, 2])
    assert isinstance(back, np.ndarray) and back.shape == (n, 3)
    np.testing.assert_allclose(back[:, :2], ground[:, :2], rtol=0, atol=1e-9)
    # a batch shape is kept
    np.testing.assert_array_equal(rpc.project(ground.reshape(1, n, 3))[0], xy)


def test_buckets_pad_by_a_quarter_at_most():
    sizes = np.unique(np.geomspace(17, 1e6, 400).astype(int))
    buckets = np.array([rpc_eval._bucket(int(n)) for n in sizes])
    assert np.all(buckets >= sizes) and np.all(buckets <= 1.25 * sizes)
    assert len(np.unique(buckets)) <= 4 * 17  # four programs per octave at most
    assert rpc_eval._bucket(1) == rpc_eval._bucket(16) == rpc_eval.MIN_BUCKET


def test_localize_flags_what_the_chord_steps_cannot_reach(pleiades):
    """Image points far outside the RPC's image (1e9 px) or NaN: NaN for those points only,
    never a stalled value passed off as converged; the others are localised as usual."""
    rpc, _ = pleiades
    go, gs = np.asarray(rpc.ground_offset), np.asarray(rpc.ground_scale)
    ground = go + gs * np.array([[0.1, -0.2, 0.3], [0.5, 0.5, -0.5], [-0.3, 0.2, 0.0]])
    xy = rpc.project(ground)
    xy[1] = [1e9, -1e9]
    xy[2, 0] = np.nan
    out = rpc.localize(xy, ground[:, 2])
    assert np.all(np.isnan(out[1, :2])) and np.all(np.isnan(out[2, :2]))
    np.testing.assert_allclose(out[0, :2], ground[0, :2], rtol=0, atol=1e-9)


def test_the_gpu_kernel_gives_the_cpu_kernel_numbers(pleiades):
    """The projection body for jax arrays on a GPU (one (n, 2) elementwise loop, no transposing
    copies) runs here on the CPU: it must give the CPU body's numbers, batch shape kept."""
    rpc, _ = pleiades
    rng = np.random.default_rng(3)
    go, gs = np.asarray(rpc.ground_offset), np.asarray(rpc.ground_scale)
    ground = jax.numpy.asarray(go + gs * rng.uniform(-0.9, 0.9, (4, 250, 3)))
    flat = rpc_eval._flat(rpc)
    gpu = np.asarray(rpc_eval._project_kernel_direct(*flat, ground))
    cpu = np.asarray(rpc_eval._project_kernel(*flat, ground))
    assert gpu.shape == (4, 250, 2)
    np.testing.assert_allclose(gpu, cpu, rtol=0, atol=1e-9)


def test_numpy_calls_run_on_the_cpu_device_when_it_is_the_default(pleiades):
    """On a GPU machine numpy projections are computed on the host's CPU device (the copies
    cost more than the projection): the same path as a CPU machine's, the same numbers."""
    rpc, _ = pleiades
    ground = np.asarray(rpc.ground_offset) + np.zeros((5, 3))
    assert rpc_eval.runs_on_cpu() == (jax.default_backend() == "cpu")
    expected = rpc.project(ground)
    with jax.default_device(rpc_eval.host_device()):
        assert rpc_eval.runs_on_cpu()
        np.testing.assert_array_equal(rpc.project(ground), expected)
