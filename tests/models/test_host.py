"""``jaxgeo.models._host``: numpy in and out of a compiled kernel without copies. The exact path
must give the chunked path's numbers, never touch the input, and hand out arrays that behave as
the user's own."""

import gc

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo.models import _host as host


@pytest.fixture(autouse=True)
def _on_the_cpu():
    """These are the CPU's paths (numpy memory used in place): on the CPU on a GPU machine too."""
    with jax.default_device(jax.local_devices(backend="cpu")[0]):
        yield


def _at_offset(values: np.ndarray, offset: int) -> np.ndarray:
    """A copy of ``values`` whose first element lies ``offset`` elements past a 64-byte
    boundary."""
    buf = np.empty(values.size + 16)
    start = (-(buf.ctypes.data % 64) // 8) % 8 + offset
    out = buf[start : start + values.size].reshape(values.shape)
    out[...] = values
    return out


@pytest.mark.parametrize("offset", range(8))
def test_aligned_flat_views_the_array_from_a_64_byte_boundary(offset):
    a = _at_offset(np.arange(30.0).reshape(10, 3), offset)
    assert a.ctypes.data % 64 == offset * 8
    flat, k = host.aligned_flat(a)
    assert k == offset and flat.ctypes.data % 64 == 0
    np.testing.assert_array_equal(flat[k:], a.ravel())
    assert not flat.flags.writeable
    # jaxlib uses it in place (no copy)
    assert jax.device_put(flat).unsafe_buffer_pointer() == flat.ctypes.data


def test_not_eligible_inputs_are_refused():
    a = np.arange(30.0).reshape(10, 3)
    for bad in (a.astype(np.float32), a[:, ::2], np.asfortranarray(a), a[:0]):
        assert not host.eligible(bad)
    with pytest.raises(ValueError, match="float64"):
        host.aligned_flat(a.astype(np.float32))


def test_writable_output_outlives_its_jax_array():
    x = jax.jit(lambda v: v * 2.0)(jnp.arange(20000.0).reshape(10000, 2))
    expected = np.asarray(x).copy()
    out = host.writable(x)
    del x
    gc.collect()
    jax.jit(lambda v: v + 1.0)(jnp.zeros((10000, 2))).block_until_ready()  # reuse freed memory
    np.testing.assert_array_equal(out, expected)
    out[0, 0] = -1.0  # the user's own array
    assert out.flags.writeable and out[0, 0] == -1.0


@pytest.mark.parametrize("offset", [0, 3, 6])
def test_a_size_used_again_runs_whole_with_the_same_numbers(pleiades, monkeypatch, offset):
    rpc, _ = pleiades
    monkeypatch.setattr(host, "EXACT_MIN", 64)
    monkeypatch.setattr(host, "_SEEN", host.Recent(host.SEEN_MAX))
    monkeypatch.setattr(host, "_PROGRAMS", host.Recent(host.PROGRAMS_MAX))
    go, gs = np.asarray(rpc.ground_offset), np.asarray(rpc.ground_scale)
    rng = np.random.default_rng(offset)
    ground = _at_offset(go + gs * rng.uniform(-0.9, 0.9, (301, 3)), offset)
    before = ground.copy()
    first = rpc.project(ground)  # a new size: the chunked path
    assert len(host._PROGRAMS) == 0
    second = rpc.project(ground)  # used again: whole, in place
    assert len(host._PROGRAMS) == 1
    np.testing.assert_array_equal(second, first)
    np.testing.assert_array_equal(ground, before)  # the input is untouched
    traced = np.asarray(jax.jit(lambda r, g: r.project(g))(rpc, ground))
    np.testing.assert_allclose(second, traced, rtol=0, atol=1e-9)
    # each call hands out its own writable array
    third = rpc.project(ground)
    third[0] = np.nan
    assert second.flags.writeable and np.all(np.isfinite(second))
    # a batch shape, and a strided input (copied first) give the same numbers
    np.testing.assert_array_equal(rpc.project(ground.reshape(7, 43, 3)).reshape(-1, 2), first)
    strided = np.repeat(ground, 2, axis=0)[::2]
    np.testing.assert_array_equal(rpc.project(strided), first)
    np.testing.assert_array_equal(rpc.project(strided), first)


def test_recent_keeps_the_last_used_keys():
    recent = host.Recent(limit=2)
    recent.put("a", 1)
    recent.put("b", 2)
    assert recent.get("a") == 1  # "a" used: "b" is now the oldest
    recent.put("c", 3)
    assert recent.get("b") is None and recent.get("a") == 1 and recent.get("c") == 3
    assert len(recent) == 2


def test_on_host_leaves_host_arrays_as_they_are():
    leaves = [jnp.arange(3.0), 2.0, np.ones(2)]
    assert host.on_host(leaves) is leaves


# a model made on another device (a GPU's part played by a second CPU device): its arrays are put
# on the host device once, and its numpy projection has the numbers of the model made there
ELSEWHERE = """
import json, jax, numpy as np
import jaxgeo
from jaxgeo.io import read_rpc
from jaxgeo.models import _host
from jaxgeo.simulate import demo_dir

cpu0, cpu1 = jax.devices()
with jax.default_device(cpu1):
    far = read_rpc(demo_dir() / "fore.txt")
near = read_rpc(demo_dir() / "fore.txt")
leaves = jax.tree.leaves(far)
moved = _host.on_host(leaves)
ground = np.asarray(near.ground_offset) + np.linspace(-0.5, 0.5, 30).reshape(10, 3) * np.asarray(
    near.ground_scale)
print(json.dumps({
    "far": sorted({str(d) for x in leaves for d in x.devices()}),
    "moved": sorted({str(d) for x in moved for d in x.devices()}),
    "again": _host.on_host(leaves) is moved,
    "new_list_hits": _host.on_host(list(leaves)) is moved,
    "equal": all(np.array_equal(a, b) for a, b in zip(leaves, moved)),
    "projection": float(np.abs(jax.tree.unflatten(jax.tree.structure(far), moved).project(ground)
                              - near.project(ground)).max()),
}))
"""


def test_on_host_puts_a_model_from_another_device_there_once():
    import json
    import os
    import pathlib
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "JAX_NUM_CPU_DEVICES"}
    repo = str(pathlib.Path(__file__).resolve().parents[2])
    env.update(JAXGEO_CPU_DEVICES="2", JAX_PLATFORMS="cpu", PYTHONPATH=repo)
    run = subprocess.run([sys.executable, "-c", ELSEWHERE], capture_output=True, text=True,
                         env=env, timeout=300)  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["far"] == ["cpu:1"] and out["moved"] == ["cpu:0"]
    assert out["again"] and out["new_list_hits"]  # cached by the arrays, not by their list
    assert out["equal"] and out["projection"] == 0.0
