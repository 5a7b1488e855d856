"""Trace-free warm calls (``jaxgeo._runtime.exported``): results bit-equal to
``eqx.filter_jit``, traced once per structure across processes, safe fall-backs."""

import importlib
import json
import logging
import os
import pathlib
import subprocess
import sys
import types

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo._runtime import executables as _executables
from jaxgeo._runtime import exported as _exported
from jaxgeo.lsq import RESULTS

REPO = pathlib.Path(__file__).resolve().parents[1]
TRACES = []


class Out(eqx.Module):
    value: jax.Array
    result: RESULTS  # an equinox enumeration item: its pickled treedef would not unflatten
    label: str = eqx.field(static=True)


def fn(x, scale, *, label="fn"):
    TRACES.append(label)  # runs only while tracing
    y = jnp.sin(x) * scale
    result = RESULTS.where(jnp.all(y < 10.0), RESULTS.successful, RESULTS.not_converged)
    return Out(y, result, label)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXGEO_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(_exported, "_loaded", {})
    TRACES.clear()
    return tmp_path / "cache" / "exported"


def test_same_results_and_traced_once_across_loads(cache):
    x = np.linspace(0.0, 3.0, 7)
    want = eqx.filter_jit(fn)(x, 2.0, label="want")
    got = _exported.call(fn, x, 2.0, label="a")
    assert TRACES == ["want", "a"]
    assert len(list(cache.glob("*.jaxexport"))) == 1
    _exported._loaded.clear()  # as a new process: the program comes from disk
    again = _exported.call(fn, x, 2.0, label="a")
    assert TRACES == ["want", "a"]  # not traced again
    for out in (got, again):
        np.testing.assert_array_equal(out.value, want.value)
        assert out.result == want.result and out.label == "a"
    # another static value or shape is another program
    _exported.call(fn, x, 3.0, label="a")
    _exported.call(fn, x[:3], 2.0, label="a")
    assert len(list(cache.glob("*.jaxexport"))) == 3


def _solve3(a, b):
    return jnp.linalg.solve(a, b)  # a LAPACK kernel on a CPU (a custom call)


def test_a_new_process_runs_the_kept_executable_without_lowering(cache, monkeypatch):
    """On a CPU the compiled executable is kept beside the program: a new process loads and runs
    it (no lowering, no compilation: jax's LAPACK set-up, an import of scipy.linalg, is not
    made either), bit for bit; a damaged one, or one that fails its first run, is compiled
    again and rewritten; a program with a custom call (a LAPACK kernel, which needs that
    set-up) keeps none."""
    monkeypatch.setattr(_exported, "_runners", {})
    compiled = []
    real_compile = _exported._compile
    monkeypatch.setattr(
        _exported, "_compile", lambda e, *a: compiled.append(e.fun_name) or real_compile(e, *a)
    )
    x = np.linspace(0.0, 3.0, 7)
    first = _exported.call(fn, x, 2.0)
    (exe,) = cache.glob(f"*{_executables.SUFFIX}")
    assert len(compiled) == 1
    _exported._loaded.clear()  # as a new process
    _exported._runners.clear()
    again = _exported.call(fn, x, 2.0)
    assert len(compiled) == 1 and TRACES == ["fn"]  # neither traced nor compiled
    np.testing.assert_array_equal(again.value, first.value)
    assert again.result == first.result and again.label == "fn"
    exe.write_bytes(b"not an executable")
    _exported._runners.clear()
    third = _exported.call(fn, x, 2.0)
    assert len(compiled) == 2 and exe.stat().st_size > 100  # compiled again, rewritten
    np.testing.assert_array_equal(third.value, first.value)
    # a kept executable that fails its first run (here: another program's) is removed, the
    # program compiled, checked and kept in its place
    _exported.call(fn, x[:3], 2.0)
    other = next(p for p in cache.glob(f"*{_executables.SUFFIX}") if p != exe)
    other.write_bytes(exe.read_bytes())
    _exported._runners.clear()
    np.testing.assert_array_equal(_exported.call(fn, x[:3], 2.0).value, first.value[:3])
    assert len(compiled) == 4 and other.read_bytes() != exe.read_bytes()
    other.unlink()
    a = np.array([[2.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 4.0]])
    np.testing.assert_allclose(_exported.call(_solve3, a, np.ones(3)) @ a.T, np.ones(3))
    assert len(list(cache.glob(f"*{_exported.SUFFIX}"))) == 3
    assert list(cache.glob(f"*{_executables.SUFFIX}")) == [exe]


def test_an_executable_read_from_jax_cache_counts_as_not_compiled_here():
    """Executables from jax's compilation cache are not kept again (serialized again, one ran
    into ``Function ... not found`` in the next process): ``compile_here`` tells them apart by
    the cache's hit event, in the compiling thread only."""
    import threading

    def hit():
        jax.monitoring.record_event("/jax/compilation_cache/cache_hits")
        return "from the cache"

    assert _executables.compile_here(hit) == ("from the cache", False)
    assert _executables.compile_here(lambda: "compiled") == ("compiled", True)
    seen = []

    def elsewhere():  # another thread's hit, while this one compiles
        worker = threading.Thread(target=hit)
        worker.start()
        worker.join()
        return "compiled"

    seen.append(_executables.compile_here(elsewhere))
    assert seen == [("compiled", True)]


def test_an_executable_from_jax_cache_is_compiled_again_past_it_once_and_kept(cache, monkeypatch):
    """A program whose key is new but whose XLA program jax's cache holds (jaxgeo upgraded, or
    its executable evicted) is compiled once more with that cache off, and kept: else every
    later process lowered it and read it from jax's cache again. One whose executable could
    not be kept is marked, and not compiled twice again."""
    monkeypatch.setattr(_exported, "_runners", {})
    calls, enabled, hit = [], [], [True]
    real_compile = _exported._compile

    def from_cache_first(e, *a):  # a compilation that "hits" jax's cache while ``hit``
        calls.append(e.fun_name)
        enabled.append(jax.config.jax_enable_compilation_cache)
        if hit[0]:
            hit[0] = False
            jax.monitoring.record_event("/jax/compilation_cache/cache_hits")
        return real_compile(e, *a)

    monkeypatch.setattr(_exported, "_compile", from_cache_first)
    was = jax.config.jax_enable_compilation_cache
    jax.config.update("jax_enable_compilation_cache", True)
    try:
        x = np.linspace(0.0, 3.0, 7)
        first = _exported.call(fn, x, 2.0)
        assert jax.config.jax_enable_compilation_cache  # restored
    finally:
        jax.config.update("jax_enable_compilation_cache", was)
    assert enabled == [True, False]  # compiled again with jax's cache off
    (exe,) = cache.glob(f"*{_executables.SUFFIX}")  # and kept
    _exported._loaded.clear()  # as a new process: loaded, neither traced nor compiled
    _exported._runners.clear()
    np.testing.assert_array_equal(_exported.call(fn, x, 2.0).value, first.value)
    assert len(calls) == 2 and TRACES == ["fn"]
    # kept meanwhile by another process (a dask worker) after this one found none: the cache
    # hit is used as it is, the file left to the next process
    real_load = _executables.load
    monkeypatch.setattr(_executables, "load", lambda *a: None)
    calls.clear()
    _exported._runners.clear()
    hit[0] = True
    _exported.call(fn, x, 2.0)
    assert len(calls) == 1 and exe.exists()
    monkeypatch.setattr(_executables, "load", real_load)
    # an executable that cannot be kept is marked: a cache hit is then used as it is
    exe.unlink()
    real_write = _exported._write

    def no_executable(path, blob, suffix=_exported.SUFFIX):
        if suffix == _executables.SUFFIX:
            raise OSError("not serializable")
        real_write(path, blob, suffix)

    monkeypatch.setattr(_exported, "_write", no_executable)
    calls.clear()
    _exported._runners.clear()
    _exported.call(fn, x, 2.0)  # compiled here (no hit): not kept, marked
    assert len(calls) == 1 and len(list(cache.glob(f"*{_executables.REFUSED}"))) == 1
    calls.clear()
    _exported._runners.clear()
    hit[0] = True
    _exported.call(fn, x, 2.0)  # a hit now: not compiled again past the cache
    assert len(calls) == 1 and not list(cache.glob(f"*{_executables.SUFFIX}"))


def test_damaged_file_is_traced_again(cache):
    x = np.ones(4)
    _exported.call(fn, x, 1.0)
    (path,) = cache.glob("*.jaxexport")
    path.write_bytes(b"not a program")
    _exported._loaded.clear()
    out = _exported.call(fn, x, 1.0)
    np.testing.assert_array_equal(out.value, np.sin(x))
    assert TRACES == ["fn", "fn"] and path.stat().st_size > 100


def test_fallbacks_off_traced_and_unpicklable(cache, monkeypatch):
    x = jnp.ones(3)
    # inside a transformation: the jitted function, differentiable
    grad = jax.grad(lambda v: _exported.call(fn, v, 2.0).value.sum())(x)
    np.testing.assert_allclose(grad, 2.0 * np.cos(1.0))
    # a static value without a stable key (a lambda): plain jit
    out = _exported.call(fn, x, 1.0, label=lambda: None)
    np.testing.assert_array_equal(out.value, np.sin(np.ones(3)))
    assert not cache.exists()
    # large inputs: plain jit (an export's slower first compilation does not pay off there)
    monkeypatch.setattr(_exported, "MAX_ELEMENTS", 2)
    np.testing.assert_array_equal(_exported.call(fn, x, 1.0).value, np.sin(np.ones(3)))
    assert not cache.exists()
    monkeypatch.setenv("JAXGEO_CACHE_DIR", "off")
    assert _exported.folder() is None
    np.testing.assert_array_equal(_exported.call(fn, x, 1.0).value, np.sin(np.ones(3)))
    assert not cache.exists()


def _mismatch(a, b, rtol: float, path: str = "") -> str | None:
    """Where two JSON values first differ (``None``: equal, numbers to ``rtol`` relative to the
    larger magnitude, 1e-12 at least): the path and both values, for the assertion's message."""
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return f"{path}: keys {sorted(a)} != {sorted(b)}"
        return next((m for k in a if (m := _mismatch(a[k], b[k], rtol, f"{path}.{k}"))), None)
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path}: {len(a)} != {len(b)} items"
        found = (_mismatch(x, b[i], rtol, f"{path}[{i}]") for i, x in enumerate(a))
        return next((m for m in found if m), None)
    if isinstance(a, float) and isinstance(b, float):
        close = abs(a - b) <= rtol * max(abs(a), abs(b), 1e-12)
    else:
        close = a == b
    return None if close else f"{path}: {a!r} != {b!r}"


def test_demo_warm_run_equals_an_uncached_run(tmp_path):
    """``jaxgeo demo --json`` twice on a fresh cache (the second loads the exported solve and
    intersections): the same numbers; and once with the cache off (plain jit with XLA's
    default code generation, where the exported programs use ``_exported.QUICK_COMPILE``'s):
    the same numbers to the last digits the solver's tolerance leaves (1e-11 of the
    parameters, measured)."""
    drop = ("JAX_COMPILATION_CACHE_DIR", "JAXGEO_CACHE_DIR", "XLA_FLAGS")
    base = {k: v for k, v in os.environ.items() if k not in drop}
    base["PYTHONPATH"] = str(REPO)
    # XLA's default code generation (the suite's legacy emitters round an exported program and
    # its plain jit differently, see tests/strip/test_solve.py), without LLVM's optimisation
    # (the test's three runs: 33 s -> 22 s)
    base["XLA_FLAGS"] = " ".join(
        ["--xla_backend_optimization_level=0", "--xla_llvm_disable_expensive_passes=true"]
    )

    def demo(cache):
        cmd = [sys.executable, "-m", "jaxgeo.cli", "demo", "--json"]
        env = dict(base, JAXGEO_CACHE_DIR=cache)
        run = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr[-2000:]
        out = json.loads(run.stdout)
        out.pop("seconds")
        return out

    cache = str(tmp_path / "c")
    first, second = demo(cache), demo(cache)
    assert list((tmp_path / "c" / "exported").glob("*.jaxexport"))
    if jax.default_backend() == "cpu":
        assert first == second
    else:  # a GPU's reductions are not bitwise repeatable, and the solver's path follows them
        # (s0 1e-13 relative apart on an H100 and an H200, where another field missed 1e-11)
        assert _mismatch(first, second, rtol=1e-8) is None, _mismatch(first, second, rtol=1e-8)
    off = demo("off")
    assert _mismatch(first, off, rtol=1e-8) is None, _mismatch(first, off, rtol=1e-8)


def test_large_inputs_compiled_apart_once_with_the_heap_released(cache, monkeypatch):
    """Inputs over ``MAX_ELEMENTS``: compiled once per structure (``lower().compile()``), the C
    heap released before each run, results bit-equal to ``eqx.filter_jit``."""
    monkeypatch.setattr(_exported, "MAX_ELEMENTS", 2)
    monkeypatch.setattr(_exported, "_compiled", {})
    released = []
    monkeypatch.setattr(_exported, "release_heap", lambda: released.append(1))
    x = np.linspace(0.0, 3.0, 5)
    want = eqx.filter_jit(fn)(x, 2.0, label="want")
    for _ in range(2):
        out = _exported.call(fn, x, 2.0, label="big")
        np.testing.assert_array_equal(out.value, want.value)
        assert out.result == want.result and out.label == "big"
    assert TRACES == ["want", "big"] and released == [1, 1]  # traced and compiled once
    _exported.call(fn, x[:4], 2.0, label="big")  # another shape: another program
    assert len(_exported._compiled) == 2 and released == [1, 1, 1]
    assert not cache.exists()  # not exported


@jax.jit
def _slow(x):
    """~0.35 s of work on a 2-core CPU, dispatched asynchronously (a while loop over matrix
    products; jax runs a while loop over small arrays inline, in the call)."""
    return jax.lax.fori_loop(0, 40, lambda i, v: jnp.sin(v @ v * 1e-3), x)


def test_large_inputs_computed_before_their_program_is_compiled(cache, monkeypatch):
    """A program compiled apart is compiled once its inputs exist: the computation that makes
    them (dispatched, still running) has freed its working memory by then (a large solve's
    iterations, then its finish), while its trace and lowering ran beside that computation."""
    monkeypatch.setattr(_exported, "MAX_ELEMENTS", 2)
    monkeypatch.setattr(_exported, "_compiled", {})
    seen = []
    compile_ = jax.stages.Lowered.compile

    def spy(self, *args, **kwargs):
        seen.append(pending.is_ready())
        return compile_(self, *args, **kwargs)

    monkeypatch.setattr(jax.stages.Lowered, "compile", spy)
    start = np.linspace(0.0, 1.0, 600 * 600).reshape(600, 600)
    _slow(start).block_until_ready()  # compiled, so that the next call only runs
    pending = _slow(start)  # dispatched: running on XLA's threads
    assert not pending.is_ready()  # (else the test would show nothing)
    out = _exported.call(fn, pending, 2.0, label="big")
    assert seen == [True]
    np.testing.assert_allclose(out.value, np.sin(np.asarray(pending)) * 2.0, rtol=1e-14)


def test_large_solve_compiled_apart_with_its_own_options(cache, monkeypatch):
    """``call_solve``: a large program compiled with ``SOLVE_COMPILE`` (XLA's legacy
    CPU emitters where jaxlib has them), apart from the same program compiled with XLA's
    defaults; results equal to ``eqx.filter_jit`` to rounding."""
    monkeypatch.setattr(_exported, "MAX_ELEMENTS", 2)
    monkeypatch.setattr(_exported, "_compiled", {})
    asked = []
    real = _exported._compiled_call

    def spy(*args):
        asked.append(args[6])  # (fn, treedef, static, leaves, args, kwargs, options, ...)
        return real(*args)

    monkeypatch.setattr(_exported, "_compiled_call", spy)
    x = np.linspace(0.0, 3.0, 5)
    want = eqx.filter_jit(fn)(x, 2.0, label="want")
    out = _exported.call_solve(fn, x, 2.0, label="big")
    np.testing.assert_allclose(out.value, want.value, rtol=1e-15, atol=0)
    _exported.call(fn, x, 2.0, label="big")
    assert asked == [_exported.SOLVE_COMPILE or None, None]
    # one program per set of options (one set only where jaxlib has no legacy emitters)
    assert len(_exported._compiled) == (2 if _exported.SOLVE_COMPILE else 1)
    small = np.ones(1)  # at most MAX_ELEMENTS: the exported path, options unused
    np.testing.assert_allclose(_exported.call_solve(fn, small, 2.0).value, np.sin(small) * 2)
    assert len(asked) == 2


@pytest.mark.parametrize("path", ["compiled apart", "exported"])
def test_solve_options_reach_xla_and_those_jaxlib_does_not_know_are_left_out(
    cache, monkeypatch, caplog, path
):
    """A solve too large for ``QUICK_COMPILE`` is compiled with ``SOLVE_COMPILE`` on both paths
    (inputs over ``MAX_ELEMENTS``: compiled apart; else exported): an option XLA refuses is
    left out, once, and logged; the result is right. Another program keeps XLA's defaults."""
    if path == "compiled apart":
        monkeypatch.setattr(_exported, "MAX_ELEMENTS", 2)
    monkeypatch.setattr(_exported, "QUICK_MAX_ELEMENTS", 0)
    monkeypatch.setattr(_exported, "_compiled", {})
    monkeypatch.setattr(_exported, "_runners", {})
    monkeypatch.setattr(
        _exported, "SOLVE_COMPILE", {**_exported.SOLVE_COMPILE, "xla_no_such": True}
    )
    x = np.linspace(0.0, 3.0, 5)
    with caplog.at_level(logging.DEBUG, logger="jaxgeo._runtime.exported"):
        out = _exported.call_solve(fn, x, 2.0)
        again = _exported.call_solve(fn, x, 2.0)
        other = _exported.call(fn, x[:4], 2.0)  # not a solve: XLA's defaults
    left_out = [r for r in caplog.records if "without ['xla_no_such']" in r.getMessage()]
    assert len(left_out) == 1
    np.testing.assert_allclose(out.value, np.sin(x) * 2.0, rtol=1e-15)
    np.testing.assert_array_equal(again.value, out.value)
    np.testing.assert_allclose(other.value, np.sin(x[:4]) * 2.0, rtol=1e-15)
    assert cache.exists() == (path == "exported")


def test_owned_process_drops_jax_caches_before_and_after_a_large_compile(cache, monkeypatch):
    """Where jaxgeo owns the process (the command line), a large program's lowering clears jax's
    tracing and lowering caches before XLA compiles it, and its compilation clears them again
    (they kept its jaxpr and lowering: 46-53 MB for the 200 000-observation pair); a library
    caller's caches are kept; the program runs alike."""
    monkeypatch.setattr(_exported, "MAX_ELEMENTS", 2)
    monkeypatch.setattr(_exported, "_compiled", {})
    x = np.linspace(0.0, 3.0, 5)
    other = jax.jit(jnp.cos)
    drops = []
    real_drop = _exported._drop_traces

    def spy():
        drops.append(len(_exported._compiled))  # programs compiled when the caches go
        real_drop()
        drops.append(other._cache_size())

    monkeypatch.setattr(_exported, "_drop_traces", spy)
    other(x)  # a caller's own jitted function, compiled before the large program
    assert other._cache_size() == 1
    out = _exported.call(fn, x, 2.0, label="library")
    assert other._cache_size() == 1 and drops == []  # not owned: left alone
    previous = _exported.own_process()
    try:
        owned = _exported.call(fn, x[:4], 2.0, label="owned")
        assert drops == [1, 0]  # dropped before it was compiled (the library one was)
        other(x)
        assert other._cache_size() == 1
        again = _exported.call(fn, x[:4], 2.0, label="owned")  # the held executable runs
        assert other._cache_size() == 1 and drops == [1, 0]  # compiled once, dropped once
        owned = _exported.call(fn, x[:3], 2.0, label="owned")  # another shape
        assert other._cache_size() == 0 and drops == [1, 0, 2, 0]
    finally:
        assert _exported.own_process(previous) is True
    np.testing.assert_array_equal(again.value, out.value[:4])
    np.testing.assert_array_equal(owned.value, out.value[:3])
    assert TRACES == ["library", "owned", "owned"]


def test_command_line_owns_the_process_only_while_it_runs(monkeypatch):
    from jaxgeo.cli import _demo, main

    seen = []
    monkeypatch.setattr(_demo, "run", lambda args: seen.append(_exported._owns_process))
    assert _exported._owns_process is False
    assert main(["demo"]) == 0
    assert seen == [True] and _exported._owns_process is False


def test_a_solve_announces_its_trace_before_it_is_compiled(cache, monkeypatch):
    """``when_solve_traced``: called for ``call_solve`` (exported or compiled apart,
    first and later calls), once the program is traced and before XLA compiles it; not for
    ``call``."""
    monkeypatch.setattr(_exported, "_compiled", {})
    seen = []

    def announce():
        seen.append(list(TRACES))  # the traces done by then

    x = np.linspace(0.0, 3.0, 5)
    with _exported.when_solve_traced(announce):
        _exported.call(fn, x, 2.0, label="plain")
        assert seen == []
        _exported.call_solve(fn, x, 3.0, label="solve")
        _exported.call_solve(fn, x, 3.0, label="solve")
        monkeypatch.setattr(_exported, "MAX_ELEMENTS", 2)
        _exported.call_solve(fn, x, 3.0, label="large")
        _exported.call_solve(fn, x, 3.0, label="large")
    assert seen == [
        ["plain", "solve"],
        ["plain", "solve"],
        ["plain", "solve", "large"],
        ["plain", "solve", "large"],
    ]


def test_release_heap_runs_anywhere():
    _exported.release_heap()  # glibc's malloc_trim on Linux, nothing elsewhere; never raises


def test_quick_compilation_only_for_small_inputs_and_outputs():
    """A program with few inputs but a large output (an orthoimage tile's positions from its
    nodes) keeps XLA's default code generation: compiled quick, it ran 5x slower."""

    def spread(x):
        return jnp.zeros((2, 1024, 1024)) + x.sum()

    def small(x):
        return jnp.sin(x)

    x = np.ones((65, 65, 2))
    spec = [jax.ShapeDtypeStruct(x.shape, x.dtype)]
    big_out = jax.export.export(jax.jit(spread))(*spec)
    small_out = jax.export.export(jax.jit(small))(*spec)
    assert _exported.compiler_options([x], small_out) == _exported.QUICK_COMPILE
    assert _exported.compiler_options([x], big_out) is None
    assert _exported.compiler_options([np.ones(_exported.QUICK_MAX_ELEMENTS)], small_out) is None


def test_a_program_is_compiled_once_whether_its_inputs_are_committed_or_not(cache, monkeypatch):
    """Inputs from numpy (uncommitted) and from an earlier program (committed to its device),
    or a mix, run the same executable: jax lowers them differently (with and without a
    sharding annotation) unless the call lays them out, and the 10 000-tie pair's re-solve was
    compiled a second time."""
    monkeypatch.setattr(_exported, "_runners", {})
    compiled = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(duration)

    x, scale = np.linspace(0.0, 3.0, 5), np.asarray(2.0)
    on_device = jax.device_put((x, scale), jax.devices()[0])
    assert all(a.committed for a in on_device)
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        first = _exported.call(fn, x, scale)
        again = _exported.call(fn, *on_device)
        mixed = _exported.call(fn, x, on_device[1])
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert len(_exported._runners) == 1
    assert len(compiled) == 1
    np.testing.assert_array_equal(again.value, first.value)
    np.testing.assert_array_equal(mixed.value, first.value)
    # the listener sees compilations: plain jit compiles the committed call again
    plain = jax.jit(lambda a, b: jnp.sin(a) * b)
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        plain(x, scale)
        plain(*on_device)
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert len(compiled) == 3


def apply(model, x):
    return model(x)


USER_MODEL = """import equinox as eqx
import jax


class Scale(eqx.Module):
    k: jax.Array

    def __call__(self, x):
        return x * self.k{}
"""


def test_code_from_outside_jaxgeo_is_traced_again_once_edited(cache, monkeypatch, tmp_path):
    """A class from outside jaxgeo in the inputs (a user's own sensor model) has its module's
    source in the key: once edited, the program is traced again (the stale one would run the old
    code without a word); a class with no source file (a notebook's) runs through plain jit,
    nothing exported."""
    monkeypatch.setattr(_exported, "_loaded", {})
    path = tmp_path / "user_model_for_exported.py"
    path.write_text(USER_MODEL.format(""))
    monkeypatch.syspath_prepend(str(tmp_path))
    import user_model_for_exported as user

    monkeypatch.setitem(sys.modules, user.__name__, user)
    x, k = np.linspace(0.0, 1.0, 4), np.asarray(2.0)
    np.testing.assert_allclose(_exported.call(apply, user.Scale(k), x), 2.0 * x)
    path.write_text(USER_MODEL.format(" + 1.0"))
    importlib.reload(user)
    np.testing.assert_allclose(_exported.call(apply, user.Scale(k), x), 2.0 * x + 1.0)
    written = sorted(cache.rglob(f"*{_exported.SUFFIX}"))
    assert len(written) == 2

    cell = types.ModuleType("notebook_cell_for_exported")  # no file behind it
    monkeypatch.setitem(sys.modules, cell.__name__, cell)
    exec(USER_MODEL.format(" - 1.0"), cell.__dict__)
    np.testing.assert_allclose(_exported.call(apply, cell.Scale(k), x), 2.0 * x - 1.0)
    assert sorted(cache.rglob(f"*{_exported.SUFFIX}")) == written
