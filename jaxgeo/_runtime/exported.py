"""Trace-free warm calls: compiled entry points kept on disk as serialized ``jax.export`` programs.

The persistent compilation cache (:mod:`._jaxconfig`) spares a second run XLA's compilation, not
jax's tracing, which is most of what is left: tracing the robust solve of ``jaxgeo demo`` takes
~4 s of Python, its arithmetic milliseconds. :func:`call` runs a pure JAX function of concrete
inputs through ``jax.export``: the first call with a new structure traces it once, exports it and
writes the serialized program (StableHLO, with its output structure) to
``<cache dir>/exported/<key>.jaxexport``; a later call -- in any process -- with the same key
loads it and runs it without tracing (its XLA executable then comes from the compilation cache).

The key (:mod:`._program_key`) is a SHA-256 of everything the program depends on: the function's
module and name, the source of every jaxgeo module (any edit gives new keys) and that of any
other module that defines the function or a class of the inputs (a user's own sensor model; one
without a source file, as in a notebook, runs through plain jit), the Python version and those
of jax, jaxlib, equinox, optimistix, lineax, jaxtyping and numpy, the ``jax.config`` options and
environment variables that change a trace, the backend, the input structure with its static
(non-array) values pickled, and each array's shape and dtype. Anything that cannot be keyed or
exported this way (an unpicklable static value, a host callback in the program) falls back to
``eqx.filter_jit`` -- slower, never different.
On a CPU the compiled executable is kept beside the program too (:mod:`.executables`): a later
process runs it without lowering the program again.
Results are those of the jitted function (the same StableHLO; tested bit for bit), compiled
with the same XLA options; small programs get quicker ones (:data:`QUICK_COMPILE`), other
solves leaner ones (:data:`SOLVE_COMPILE`), whose roundings may differ from XLA's defaults in
the last bits (a solve then stops within its tolerance of the same point).

Off with the compilation cache (``JAXGEO_CACHE_DIR=off``), inside transformations (tracers in
the inputs) and for inputs over ``MAX_ELEMENTS`` (but those of a kernel, :func:`call_kernel`):
then :func:`call` is ``eqx.filter_jit(fn)``. Inputs over ``MAX_ELEMENTS`` are compiled apart
from their first run (``lower().compile()``, kept per structure), and the C heap's free pages
are given back to the OS before each run
(:func:`release_heap`): compiling a large program leaves hundreds of MB of freed memory in
the allocator's arenas (the 200 000-observation pair: 810 -> 530 MB), and the caller's work
between two runs tens (26 MB before a re-solve of that pair), on top of which the run would
allocate its working memory.
Where jaxgeo owns the process (the command line, :func:`own_process`), jax's own caches are
cleared before and after a large program is compiled: they held its jaxpr and MLIR lowering
(46-53 MB for that pair) through its compilation and every run.
Files are written atomically; at most ``MAX_ENTRIES`` are kept (least recently used first out).

jaxgeo's modules do not call this module: they declare their kept programs where the functions
are defined (:mod:`.kept`: ``@kept``, ``@kept_points``, ``kept_solve``), which calls
:func:`call`, :func:`call_kernel` and :func:`call_solve` as it decides.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import gc
import importlib.metadata
import logging
import math
import os
import pickle
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import equinox as eqx
import jax

from . import executables
from .jaxconfig import cache_dir
from .program_key import key as _key

SUFFIX = ".jaxexport"
MAX_ELEMENTS = 1_000_000
"""Inputs larger than this (array elements in all) run through plain jit: an exported program
is lowered twice and compiled more slowly on its first run (a 200 000-observation pair: 25 s
cold against 20 s), which the tracing it saves repays only where tracing dominates, as in small
problems (the demo: 6.6 -> 2.7 s warm, +0.7 s cold)."""
QUICK_MAX_ELEMENTS = 100_000
"""Programs whose inputs and outputs together hold at most this many array elements (a pair with
a few thousand ties, the demo) are compiled with :data:`QUICK_COMPILE`: their run takes
milliseconds, their compilation seconds. The outputs count: an orthoimage tile's positions (2 M
values from 8 000 node coordinates) ran 5x slower so compiled (120 against 21 ms a tile)."""
QUICK_COMPILE = {
    "xla_backend_optimization_level": 0,
    "xla_llvm_disable_expensive_passes": True,
    "xla_cpu_use_fusion_emitters": False,
    "xla_cpu_parallel_codegen_split_count": 1,
}
"""XLA options (``jax.jit(compiler_options=...)``) of small programs: LLVM without its expensive
optimisations, XLA's legacy CPU emitters, and LLVM's code generation in one piece (not split
over threads). ``jaxgeo demo`` cold: 32.5 -> 19.3 s of CPU time (2-core AVX-512 CPU, same
output); in one piece, the demo's solve and intersection compile with 5-10 % less CPU time
(2.61 -> 2.37 s and 0.97 -> 0.89 s, best of 5; the split's threads compete with the
demo's other thread on 2 cores). An elementwise 1e6-point kernel runs 10 % slower with these
options, which is why large programs keep XLA's defaults (solves: :data:`SOLVE_COMPILE`). The
test suite sets the first three for every program (tests/conftest.py; the fourth changed its
run time by -8 and +3 % in two pairs of runs). jaxlib 0.11 has no fusion-emitter option
(XLA refuses an option it does not know): there it is left out."""
with contextlib.suppress(importlib.metadata.PackageNotFoundError, ValueError):
    if tuple(int(v) for v in importlib.metadata.version("jaxlib").split(".")[:2]) >= (0, 11):
        del QUICK_COMPILE["xla_cpu_use_fusion_emitters"]
SOLVE_COMPILE = {
    "xla_cpu_use_fusion_emitters": False,
    "xla_cpu_scheduler_type": "CPU_SCHEDULER_TYPE_MEMORY_OPTIMIZED",
}
"""XLA options of a solve (:func:`call_solve`) too large for :data:`QUICK_COMPILE`, exported
or compiled apart: XLA's legacy CPU emitters and its memory-optimising scheduler; the run takes
as long as with XLA's defaults. The 200 000-observation pair's solve (compiled apart):
compiling it with the legacy emitters took the process from 473 to 550 MB instead of 814 (7.1 s
instead of 8.2); the scheduler brings the run's working memory from 161 to 138 MB; the run
takes as long (2.1 s, 2-core Intel Xeon). A 10 000-tie pair (exported; ``jaxgeo adjust``, 2-core
AMD EPYC, jaxlib 0.10.2): cold 18.1 -> 15.5 s, peak 754 -> 546 MB, warm 4.44 -> 4.41 s; the
80-scene strip (``jaxgeo strip``): cold 19.7 -> 16.8 s, peak 842 -> 538 MB, warm 4.9 -> 4.3
s. Options the jaxlib does not know are left out (jaxlib 0.11 has no fusion-emitter
option)."""
with contextlib.suppress(importlib.metadata.PackageNotFoundError, ValueError):
    if tuple(int(v) for v in importlib.metadata.version("jaxlib").split(".")[:2]) >= (0, 11):
        del SOLVE_COMPILE["xla_cpu_use_fusion_emitters"]
MAX_ENTRIES = 200
"""Exported programs kept on disk (~0.3 MB each), and as many executables (up to a few MB);
older ones are removed when more are written."""

_log = logging.getLogger(__name__)
_owns_process = False
_solve_hooks = threading.local()
_loaded: dict[str, tuple[Any, Any, Any]] = {}
_compiled: dict[str, Any] = {}
_runners: dict[tuple[str, Any], Callable] = {}


def own_process(owns: bool = True) -> bool:
    """Tell this module whether jaxgeo owns the process (the command line does; a library
    caller's session does not). Then jax's tracing, lowering and dispatch caches
    (``jax.clear_caches``) are cleared once a large program is lowered, before XLA compiles it
    (:func:`_compiled_call`), and again once it is compiled: they keep the large program's
    jaxpr and its MLIR lowering, which nothing needs once the executable is held. Held
    through the 200 000-observation pair's solves they took 46-53 MB; held through its
    compilation, which on jaxlib 0.12 (XLA's fusion emitters, no legacy option) grows the
    process by ~280 MB, ~50 MB of its peak (654 -> 606 MB, 2-core AMD EPYC). Other programs are
    traced again if called again (their XLA executables come from the compilation cache). A
    library caller's caches are left alone. Returns the previous setting."""
    global _owns_process
    previous, _owns_process = _owns_process, bool(owns)
    return previous


@contextlib.contextmanager
def when_solve_traced(callback: Callable[[], None]) -> Iterator[None]:
    """Within this block, in this thread: ``callback()`` is called each time a solve
    (:func:`call_solve`) has been traced, before XLA compiles (or, warm, runs) it. Work
    on another thread started then does not compete with the trace for the GIL; XLA's
    compilation and runs release it (``jaxgeo demo`` cold: the direct georeferencing, traced
    beside the solve's trace, delayed it by ~1 s on 2 cores). The hook of
    :func:`.kept.beside_solve`, which starts such work."""
    previous = getattr(_solve_hooks, "callback", None)
    _solve_hooks.callback = callback
    try:
        yield
    finally:
        _solve_hooks.callback = previous


def _solve_traced() -> None:
    callback = getattr(_solve_hooks, "callback", None)
    if callback is not None:
        callback()


def _nothing() -> None:
    pass


def _drop_traces() -> None:
    """jax's tracing caches cleared, their cycles collected, the heap trimmed: called between
    a large program's lowering and its compilation (see :func:`own_process`)."""
    jax.clear_caches()
    gc.collect()
    release_heap()


def release_heap() -> None:
    """Return the C heap's free pages to the OS (glibc's ``malloc_trim``; nothing elsewhere)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        trim = ctypes.CDLL(None).malloc_trim  # glibc only (not musl)
    except (OSError, AttributeError):
        return
    trim(0)


@functools.cache
def _filter_jit(fn: Callable) -> Callable:
    return eqx.filter_jit(fn)


def folder() -> Path | None:
    """Where exported programs live, ``None`` when the compilation cache is off."""
    base = cache_dir()
    if base is None:
        return None
    env = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    return (Path(env) if env else base) / "exported"


def _export(fn: Callable, treedef, static, leaves):
    """Trace ``fn`` once on the leaves' shapes; returns the Exported and the output structure."""
    from jax import export

    out_parts = {}

    def flat(*lv):
        args, kwargs = eqx.combine(jax.tree.unflatten(treedef, lv), static)
        out_dyn, out_static = eqx.partition(fn(*args, **kwargs), eqx.is_array)
        out_leaves, out_def = jax.tree.flatten(out_dyn)
        out_parts["def"], out_parts["static"] = out_def, out_static
        return out_leaves

    specs = [
        jax.ShapeDtypeStruct(x.shape, x.dtype, weak_type=bool(getattr(x, "weak_type", False)))
        for x in leaves
    ]
    exported = export.export(jax.jit(flat))(*specs)
    return exported, out_parts["def"], out_parts["static"]


def _write(path: Path, blob: bytes, suffix: str = SUFFIX) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(blob)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    entries = sorted(path.parent.glob(f"*{suffix}"), key=lambda p: p.stat().st_mtime)
    for old in entries[:-MAX_ENTRIES]:
        old.unlink(missing_ok=True)


def _program(where: Path, fn: Callable, treedef, static, leaves):
    """``(key, exported program, output structure, output statics)`` for this call (memory,
    disk under ``where``, or traced now), or ``None``."""
    try:
        key = _key(fn, treedef, static, leaves)
    except Exception:  # an unpicklable static value: no stable key
        return None
    if key in _loaded:
        return (key, *_loaded[key])
    from jax import export

    path = where / f"{key}{SUFFIX}"
    try:
        blob, template, out_static = pickle.loads(path.read_bytes())
        found = (export.deserialize(blob), jax.tree.structure(template), out_static)
        with contextlib.suppress(OSError):  # recently used (a read-only cache stays as it is)
            os.utime(path)
    except FileNotFoundError:
        found = None
    except Exception as err:  # a damaged or foreign file: traced again and rewritten
        _log.debug("exported program %s unreadable (%s): tracing again", path, err)
        found = None
    if found is None:
        try:
            exported, out_def, out_static = _export(fn, treedef, static, leaves)
            # the output structure as a tree of placeholders, not a PyTreeDef: the pickled
            # treedef of an equinox enumeration item does not unflatten
            template = jax.tree.unflatten(out_def, list(range(out_def.num_leaves)))
            blob = pickle.dumps((exported.serialize(), template, out_static), protocol=4)
        except Exception as err:  # not exportable (e.g. a host callback): plain jit
            _log.debug("%s not exported (%s)", fn.__qualname__, err)
            return None
        try:
            _write(path, blob)
        except OSError as err:  # a read-only cache: this process keeps the program in memory
            _log.debug("exported program not written to %s (%s)", path, err)
        found = (exported, out_def, out_static)
    _loaded[key] = found
    return (key, *found)


def _elements(arrays) -> int:
    return sum(math.prod(x.shape) for x in arrays)


def compiler_options(leaves, exported) -> dict | None:
    """:data:`QUICK_COMPILE` for a program whose inputs ``leaves`` and outputs hold at most
    :data:`QUICK_MAX_ELEMENTS` elements, else ``None`` (XLA's defaults)."""
    quick = _elements(leaves) + _elements(exported.out_avals) <= QUICK_MAX_ELEMENTS
    return QUICK_COMPILE if quick else None


def call(fn: Callable, *args, **kwargs):
    """``eqx.filter_jit(fn)(*args, **kwargs)``, traced at most once per structure across runs
    (see the module docstring). ``fn`` must be a module-level pure function."""
    return _call(None, fn, args, kwargs)


def call_solve(fn: Callable, *args, **kwargs):
    """:func:`call` of a solve: compiled with :data:`SOLVE_COMPILE` unless small enough for
    :data:`QUICK_COMPILE`; ``when_solve_traced``'s callback is called once it is traced."""
    return _call(SOLVE_COMPILE or None, fn, args, kwargs, traced=_solve_traced)


def compiled_apart(*args, **kwargs) -> bool:
    """Whether :func:`call` compiles a program of these inputs apart (over
    :data:`MAX_ELEMENTS` array elements)."""
    dynamic, _ = eqx.partition((args, kwargs), eqx.is_array)
    return _elements(jax.tree.leaves(dynamic)) > MAX_ELEMENTS


def call_kernel(fn: Callable, *args, **kwargs):
    """:func:`call` of a kernel run many times (a chunk of many points, a tile of pixels):
    compiled with XLA's defaults whatever its size, its run mattering more than its
    compilation, and exported whatever its size (never compiled apart: a kernel's compilation
    needs little memory, and a large one -- an orthoimage tile's 2 M positions -- is traced
    again in every process otherwise: 30-50 ms of each ``jaxgeo ortho``). 8 192 points of
    an RPC localised (projected) 3.4x (2.8x) faster than with :data:`QUICK_COMPILE` (2-core
    AMD EPYC, jaxlib 0.10.2)."""
    return _call(None, fn, args, kwargs, quick=False, apart=False)


def _call(
    solve: dict | None,
    fn: Callable,
    args,
    kwargs,
    traced: Callable[[], None] = _nothing,
    quick: bool = True,
    apart: bool = True,
):
    """``solve``: the XLA options of a program too large for :data:`QUICK_COMPILE` (``None``:
    XLA's defaults); ``quick=False``: never :data:`QUICK_COMPILE`; ``apart=False``: exported
    whatever the inputs' size (never compiled apart). ``traced()`` is called once
    the program is traced (or found), before it is compiled or run; on the plain-jit fall-backs
    (which trace, compile and run in one call) before that."""
    dynamic, static = eqx.partition((args, kwargs), eqx.is_array)
    leaves, treedef = jax.tree.flatten(dynamic)
    where = folder()
    if any(isinstance(x, jax.core.Tracer) for x in leaves):
        traced()
        return _filter_jit(fn)(*args, **kwargs)
    if apart and _elements(leaves) > MAX_ELEMENTS:
        return _compiled_call(fn, treedef, static, leaves, args, kwargs, solve, traced)
    program = None if where is None else _program(where, fn, treedef, static, leaves)
    traced()
    if program is None:
        return _filter_jit(fn)(*args, **kwargs)
    key, exported, out_def, out_static = program
    device = _device(leaves)
    runner = _runners.get((key, device))
    out_leaves = None
    if runner is None:
        runner = executables.load(where, key, device)
        if runner is not None:
            out_leaves = executables.first_run(runner, leaves, where, key, device)
            runner = None if out_leaves is None else runner
    if runner is None:
        options = dict((quick and compiler_options(leaves, exported)) or solve or {})
        # inputs laid out on ``device`` by the call itself, committed or not: jax lowers a
        # committed input with a sharding annotation and an uncommitted one (numpy, a fresh
        # transfer) without, so the same program called with a different mix was lowered and
        # compiled again (the 10 000-tie pair's re-solve after a snooping round, its inputs
        # partly the first solve's outputs: another 4.7 s); placing them first with
        # ``device_put`` cost 0.45 ms a call (7 leaves), twice the run of a 512-point projection
        place = None if device is None else jax.sharding.SingleDeviceSharding(device)
        wanted = functools.partial(executables.wanted, where, key, device, exported)
        while True:  # compiled at the first call
            try:
                runner, compiled_here = executables.compile_here(
                    functools.partial(_compile, exported, leaves, place, options), keep=wanted
                )
                break
            except Exception as err:
                if not _left_out(options, err, fn):
                    raise
        out_leaves = runner(*leaves)
        if compiled_here:
            executables.keep(where, key, device, runner, exported, leaves, out_leaves)
    elif out_leaves is None:
        out_leaves = runner(*leaves)
    _runners[(key, device)] = runner
    return eqx.combine(jax.tree.unflatten(out_def, out_leaves), out_static)


def _compile(exported, leaves, place, options: dict):
    """The exported program lowered and compiled for ``leaves`` (``jax.stages.Compiled``: it
    runs inputs committed to its device or not, without compiling again)."""
    jitted = jax.jit(exported.call, in_shardings=place, compiler_options=options or None)
    return jitted.lower(*leaves).compile()


def _device(leaves: list):
    """The device a program runs on: that of the leaves already committed (outputs of an earlier
    program), else jax's default device; ``None`` for leaves committed to several devices (left
    for jit to report)."""
    devices = {d for x in leaves if isinstance(x, jax.Array) and x.committed for d in x.devices()}
    if len(devices) > 1:
        return None
    return devices.pop() if devices else _default_device()


def _default_device():
    """The device jax puts uncommitted inputs on (``jax_default_device``, else the first)."""
    default = jax.config.jax_default_device
    if default is None:
        return jax.devices()[0]
    return jax.devices(default)[0] if isinstance(default, str) else default


def _left_out(options: dict, err: Exception, fn: Callable) -> bool:
    """Remove from ``options`` those that ``err`` (a compilation's) names: options this jaxlib
    does not know. Whether there were any (else ``err`` is another error)."""
    unknown = [k for k in options if f"'{k}'" in str(err)]
    if unknown:
        _log.debug("compiling %s without %s: %s", fn.__qualname__, unknown, err)
    for k in unknown:
        del options[k]
    return bool(unknown)


def _compiled_call(
    fn: Callable, treedef, static, leaves, args, kwargs, options=None, traced=_nothing
):
    """``eqx.filter_jit(fn)(*args, **kwargs)``, compiled apart (once per structure and XLA
    ``options`` in this process) with the heap released before each run (see the module
    docstring); ``traced`` as in :func:`_call`."""
    try:
        key = _key(fn, treedef, static, leaves) + repr(sorted((options or {}).items()))
    except Exception:  # an unpicklable static value: no stable key
        traced()
        return _filter_jit(fn)(*args, **kwargs)
    compiled = _compiled.get(key)
    if compiled is None:
        lowered = _filter_jit(fn).lower(*args, **kwargs)
        traced()
        # the inputs computed first: the program that makes them (dispatched, still running
        # on XLA's threads) frees its working memory before this one's compilation takes its
        # own (a large solve's iterations, then its finish: 200 000 observations, jaxlib
        # 0.12.1, cauchy: the iterations' ~110 MB had been held through the finish's
        # compilation); the trace and lowering above still ran beside it
        jax.block_until_ready(leaves)
        if _owns_process:  # the trace, before XLA's compilation adds its own memory
            _drop_traces()
        options = dict(options or {})
        while True:
            try:
                compiled = lowered.compile(compiler_options=options or None)
                break
            except Exception as err:  # an option this jaxlib does not know: left out
                if not _left_out(options, err, fn):
                    raise
        _compiled[key] = compiled
        if _owns_process:  # the large program's lowering, kept by jax (own_process)
            jax.clear_caches()
    else:
        traced()
    release_heap()  # before every run: the caller's freed memory too (26 MB before a re-solve)
    return compiled(*args, **kwargs)
