"""Kept programs declared at a function's definition (``jaxgeo._runtime.kept``): the results of
the jitted function, keyed by the undecorated function, chunked point kernels, a solve as one or
two programs, work beside a solve's compilation."""

import threading

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo._runtime import exported as _exported
from jaxgeo._runtime import program_key
from jaxgeo._runtime.kept import beside_solve, kept, kept_points, kept_solve

TRACES = []


def _sine(x, scale):
    TRACES.append("sine")  # runs only while tracing
    return jnp.sin(x) * scale


sine = kept(_sine)


@kept
def twin(x, scale):
    TRACES.append("twin")
    return jnp.sin(x) * scale


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXGEO_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(_exported, "_loaded", {})
    monkeypatch.setattr(_exported, "_runners", {})
    monkeypatch.setattr(_exported, "_compiled", {})
    TRACES.clear()
    return tmp_path / "cache" / "exported"


def test_a_kept_function_is_the_jitted_one_keyed_by_the_undecorated_function(cache, monkeypatch):
    """Called like the function: the result of ``eqx.filter_jit`` bit for bit, traced once across
    processes; its program is the undecorated function's (the same key, the same file), and two
    functions of the same body have two programs."""
    x, scale = np.linspace(0.0, 3.0, 7), np.asarray(2.0)
    want = eqx.filter_jit(_sine)(x, scale)
    TRACES.clear()
    exported = []
    real_export = _exported._export
    monkeypatch.setattr(
        _exported, "_export", lambda fn, *a: exported.append(fn) or real_export(fn, *a)
    )
    got = sine(x, scale)
    np.testing.assert_array_equal(got, want)
    assert exported == [_sine] and sine.__wrapped__ is _sine and sine.__name__ == "_sine"
    _exported._loaded.clear()  # as a new process: the program comes from disk
    np.testing.assert_array_equal(sine(x, scale), want)
    np.testing.assert_array_equal(_exported.call(_sine, x, scale), want)  # the same program
    assert TRACES == ["sine"] and len(list(cache.glob("*.jaxexport"))) == 1
    dynamic, static = eqx.partition(((x, scale), {}), eqx.is_array)  # as exported.call does
    leaves, treedef = jax.tree.flatten(dynamic)
    keys = {program_key.key(fn, treedef, static, leaves) for fn in (_sine, twin.__wrapped__)}
    assert len(keys) == 2  # two functions, two keys
    np.testing.assert_array_equal(twin(x, scale), want)
    assert len(list(cache.glob("*.jaxexport"))) == 2


def test_a_kept_function_in_a_transformation_is_the_jitted_function(cache):
    x = jnp.linspace(0.0, 1.0, 4)
    grad = jax.grad(lambda v: sine(v, 2.0).sum())(x)
    np.testing.assert_allclose(grad, 2.0 * np.cos(np.asarray(x)), rtol=1e-14)
    batched = jax.jit(jax.vmap(lambda v: sine(v, 3.0)))(x[:, None])
    np.testing.assert_allclose(batched[:, 0], 3.0 * np.sin(np.asarray(x)), rtol=1e-14)
    assert not cache.exists()  # nothing exported from inside a trace


class Scale(eqx.Module):
    k: jax.Array


@kept_points((4, 16))
def _scaled(model, xy, h):
    TRACES.append("points")
    return jnp.concatenate([xy * model.k, h[:, None]], axis=-1), h * 2.0


def test_kept_points_any_number_of_points_from_two_programs(cache, monkeypatch):
    """Below the large chunk in small chunks (quick), from there on in large ones (XLA's
    defaults, ``call_kernel``); the last chunk padded; the function's own results for any number
    of points, none included; two programs in all."""
    kernels = []
    real_kernel = _exported.call_kernel
    monkeypatch.setattr(
        _exported, "call_kernel", lambda fn, *a: kernels.append(len(a[1])) or real_kernel(fn, *a)
    )
    model = Scale(np.asarray(3.0))
    rng = np.random.default_rng(0)
    for n in (0, 3, 5, 15, 16, 40):
        xy, h = rng.normal(size=(n, 2)), rng.normal(size=n)
        out, twice = _scaled(model, xy, h)
        assert isinstance(out, np.ndarray) and out.shape == (n, 3) and twice.shape == (n,)
        np.testing.assert_array_equal(out, np.concatenate([xy * 3.0, h[:, None]], axis=-1))
        np.testing.assert_array_equal(twice, h * 2.0)
    assert kernels == [16] * (1 + 3)  # 16 points: one large chunk, 40: three
    assert TRACES == ["points", "points"] and len(_exported._runners) == 2
    # one chunk size: chunks of it whatever the number of points, never ``call_kernel``
    one_size = kept_points(4)(_scaled.__wrapped__)
    xy, h = rng.normal(size=(40, 2)), rng.normal(size=40)
    np.testing.assert_array_equal(one_size(model, xy, h)[1], h * 2.0)
    assert kernels == [16] * (1 + 3) and TRACES == ["points", "points"]
    # within a transformation: the function on all the points, jitted
    xy = jnp.ones((5, 2))
    out, _ = jax.jit(lambda v: _scaled(model, v, jnp.zeros(5)))(xy)
    np.testing.assert_array_equal(out[:, :2], 3.0 * np.ones((5, 2)))


def _whole(x, scale, *, shift):
    return _finish(x, scale, _first(x, scale, shift=shift), shift=shift)


def _first(x, scale, *, shift):
    TRACES.append("first")
    return jnp.sin(x) * scale


def _finish(x, scale, done, *, shift):
    TRACES.append("finish")
    return done + x + shift


solved = kept_solve(_whole, parts=(_first, _finish))


def test_a_kept_solve_is_one_program_or_two_for_large_inputs(cache, monkeypatch):
    """One program (the whole solve), or over ``MAX_ELEMENTS`` two compiled apart (its first
    part, then the finish of its outputs); inside a transformation the whole, jitted; the same
    results every way."""
    programs = []
    real = _exported.call_solve
    monkeypatch.setattr(
        _exported,
        "call_solve",
        lambda fn, *a, **k: programs.append(fn.__name__) or real(fn, *a, **k),
    )
    x, scale = np.linspace(0.0, 3.0, 5), np.asarray(2.0)
    want = np.sin(x) * 2.0 + x + 1.0
    np.testing.assert_allclose(solved(x, scale, shift=1.0), want, rtol=1e-14)
    assert programs == ["_whole"] and not _exported._compiled
    monkeypatch.setattr(_exported, "MAX_ELEMENTS", 2)
    np.testing.assert_allclose(solved(x, scale, shift=1.0), want, rtol=1e-14)
    assert programs == ["_whole", "_first", "_finish"] and len(_exported._compiled) == 2
    traced = jax.jit(lambda v: solved(v, scale, shift=1.0))(x)
    np.testing.assert_allclose(traced, want, rtol=1e-14)
    assert programs[3:] == ["_whole"]


def test_work_beside_a_solve_starts_once_it_is_traced(cache):
    """``beside_solve``: the work waits for the solve's trace (then runs on another thread),
    starts at the block's end when no solve ran, and never runs after the block's error."""
    events = []

    def work(label):
        events.append((label, list(TRACES), threading.current_thread() is threading.main_thread()))
        return label

    x, scale = np.linspace(0.0, 3.0, 5), np.asarray(2.0)
    with beside_solve(work, "beside") as future:
        sine(x, scale)  # not a solve: the work waits
        solved(x, scale, shift=1.0)
    assert future.result() == "beside"
    assert events == [("beside", ["sine", "first", "finish"], False)]
    with beside_solve(work, "no solve") as future:
        pass
    assert future.result() == "no solve"
    with pytest.raises(ValueError, match="failed"), beside_solve(work, "abandoned") as future:
        raise ValueError("failed")
    assert future.result() is None and [e[0] for e in events] == ["beside", "no solve"]
    with beside_solve(None, "nothing") as future:
        solved(x, scale, shift=1.0)
    assert future.result() is None


def test_no_module_outside_the_runtime_decides_how_a_function_compiles():
    """Geometry and workflows declare kept programs where functions are defined; none calls the
    exported machinery or names its compile strategies (the command line only says that it owns
    the process: ``exported.own_process``)."""
    import pathlib

    import jaxgeo

    strategy = ("exported.call", "call_kernel", "call_solve", "compiled_apart", "QUICK_COMPILE",
                "SOLVE_COMPILE", "when_solve_traced", "_solve_traced")  # fmt: skip
    root = pathlib.Path(jaxgeo.__file__).parent
    found = [
        f"{path.relative_to(root)}: {name}"
        for path in sorted(root.rglob("*.py"))
        if "_runtime" not in path.relative_to(root).parts
        for name in strategy
        if name in path.read_text()
    ]
    assert found == []
