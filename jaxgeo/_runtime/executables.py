"""Compiled executables kept beside the exported programs (:mod:`.exported`), on a CPU.

A kept program (a serialized ``jax.export`` program) spares a warm process the trace; running
it still took its lowering (``jax.jit`` of the exported call: a few tens of ms a program) and,
at the first lowering of a process, jax's LAPACK set-up, which imports ``scipy.linalg`` (0.25 s
of every warm ``jaxgeo ortho``, whose programs call no LAPACK kernel), then a look-up in the
compilation cache. :func:`keep` writes the executable itself
(:func:`jax.experimental.serialize_executable.serialize`) beside the program once it is
compiled; :func:`load` gives it back to a later process, which runs it at once.

An executable is kept only when this process compiled it, and only once a copy read back from
its file has run on the program's first inputs and given the same outputs, bit for bit: XLA's
CPU executables do not always survive serialization -- one that came out of jax's compilation
cache, serialized again, ran into ``NOT_FOUND: Function slice_bitcast_fusion.9 not found`` in
the next process (jaxlib 0.10.2). A kept executable that still fails its first run in a process
is removed, and the program lowered and compiled as without it (:func:`first_run`).
A program whose executable came from jax's cache although it could be kept (:func:`wanted`:
its key is new, e.g. after an upgrade of jaxgeo, but not its XLA program) is compiled once
more past that cache (:func:`compile_here`), so that the next process loads it: else every
later process lowered it and read it from jax's cache again, for good (a warm 1000 px
``jaxgeo ortho``: 0.41 s of CPU in its five programs, 0.19 s with them kept; main, 2-core
AMD EPYC).

Its file name (``<sha256>.xlaexe``) holds the program's key, the device (id and kind), the
jaxlib platform version and the CPU model with its instruction set extensions: a cache shared
between machines never runs an executable built for another CPU. Not kept: programs with custom
calls (LAPACK kernels need jax's own set-up, made when a program is lowered) and anything on
another backend (the compilation cache serves there). A file that cannot be read is ignored
(the program is compiled again and the file rewritten); nothing here raises.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import os
import pickle
import platform
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np

SUFFIX = ".xlaexe"
REFUSED = ".unkept"
"""Beside an executable's path: an empty file marking a program whose executable :func:`keep`
could not keep (not serializable, or its copy failed): not compiled past the cache again."""

_log = logging.getLogger(__name__)
_hits = threading.local()
_listening = threading.Lock()
_past = threading.Lock()


def _on_event(event: str, **kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits":  # called in the compiling thread
        _hits.count = getattr(_hits, "count", 0) + 1


@functools.cache
def _listen() -> bool:
    """Whether jax's cache hits are heard (a jax without this monitoring API: never)."""
    import jax

    try:
        jax.monitoring.register_event_listener(_on_event)
    except Exception as err:
        _log.debug("jax's cache hits not heard (%s): no executable kept", err)
        return False
    return True


def compile_here(
    compile: Callable[[], object], keep: Callable[[], bool] | None = None
) -> tuple[object, bool]:
    """``compile()`` (a ``jax.stages.Compiled``), and whether XLA compiled it in this call (not
    read from jax's compilation cache, whose executables, serialized again, may not run;
    ``False`` where that cannot be told). ``keep``: asked once jax's cache has served the
    program (:func:`wanted`, bound to it); where it says so, the program is compiled again,
    past the cache, so that it can be kept."""
    with _listening:
        heard = _listen()
    before = getattr(_hits, "count", 0)
    compiled = compile()
    here = heard and getattr(_hits, "count", 0) == before
    if heard and not here and keep is not None and keep():
        before = getattr(_hits, "count", 0)
        compiled = _past_the_cache(compile)
        here = getattr(_hits, "count", 0) == before
    return compiled, here


def _past_the_cache(compile: Callable[[], object]) -> object:
    """``compile()`` with jax's compilation cache off (reset before and after, as jax reads
    the setting once per use of the cache)."""
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    with _past:
        was = jax.config.jax_enable_compilation_cache
        jax.config.update("jax_enable_compilation_cache", False)
        compilation_cache.reset_cache()
        try:
            return compile()
        finally:
            jax.config.update("jax_enable_compilation_cache", was)
            compilation_cache.reset_cache()


@functools.cache
def host_signature() -> str:
    """What a CPU executable depends on beyond its program: the machine, the CPU model and its
    instruction set extensions (one compiled with AVX-512 does not run without them), read
    once from ``/proc/cpuinfo`` (elsewhere: the machine name only)."""
    text = ""
    with contextlib.suppress(OSError):
        text = Path("/proc/cpuinfo").read_text()
    wanted = ("model name", "flags", "cpu family", "model\t")
    lines = sorted({line for line in text.splitlines() if line.startswith(wanted)})
    return "\n".join([platform.machine(), *lines])


def path(where: Path | None, key: str, device) -> Path | None:
    """Where the executable of program ``key`` on ``device`` is kept; ``None``: not kept (no
    cache, or not a CPU)."""
    if where is None or device is None or device.platform != "cpu":
        return None
    what = (key, device.id, device.device_kind, device.client.platform_version, host_signature())
    return where / f"{hashlib.sha256(repr(what).encode()).hexdigest()}{SUFFIX}"


def wanted(where: Path | None, key: str, device, exported) -> bool:
    """Whether :func:`keep` would keep the executable of program ``key`` (``exported``) on
    ``device`` and none is kept yet: a CPU and a cache, no custom call, not refused before
    (:data:`REFUSED`), no file (another process, a dask worker, may have kept it meanwhile: the
    next process loads that one)."""
    file = path(where, key, device)
    if file is None or file.exists() or file.with_suffix(REFUSED).exists():
        return False
    if not os.access(file.parent, os.W_OK):  # a read-only cache: nothing is kept there
        return False
    try:
        return "custom_call" not in exported.mlir_module()
    except Exception:
        return False


def load(where: Path | None, key: str, device):
    """The kept executable of program ``key`` on ``device`` (a ``jax.stages.Compiled``, called
    with the program's input leaves), or ``None``."""
    file = path(where, key, device)
    if file is None:
        return None
    from jax.experimental.serialize_executable import deserialize_and_load

    try:
        payload, in_tree, out_tree = pickle.loads(file.read_bytes())
        compiled = deserialize_and_load(payload, in_tree, out_tree, backend=device.client,
                                        execution_devices=[device])  # fmt: skip
    except FileNotFoundError:
        return None
    except Exception as err:  # a damaged or foreign file: removed, compiled again, rewritten
        _log.debug("kept executable %s unreadable (%s): compiling again", file, err)
        with contextlib.suppress(OSError):
            file.unlink(missing_ok=True)
        return None
    with contextlib.suppress(OSError):  # recently used (a read-only cache stays as it is)
        os.utime(file)
    return compiled


def _same(a: list, b: list) -> bool:
    return len(a) == len(b) and all(
        np.array_equal(np.asarray(x), np.asarray(y), equal_nan=np.asarray(x).dtype.kind in "fc")
        for x, y in zip(a, b, strict=True)
    )


def first_run(compiled, leaves: list, where: Path | None, key: str, device):
    """The outputs of a loaded executable's first run in this process, computed and checked to
    have run; ``None`` where it failed (its file removed: the caller compiles the program)."""
    import jax

    try:
        return jax.block_until_ready(compiled(*leaves))
    except Exception as err:
        _log.debug("kept executable of program %s failed (%s): removed", key, err)
        file = path(where, key, device)
        if file is not None:
            file.unlink(missing_ok=True)
        return None


def keep(where: Path | None, key: str, device, compiled, exported, leaves, outputs) -> None:
    """Write ``compiled`` (the ``jax.stages.Compiled`` of the exported program ``exported``,
    key ``key``, on ``device``, compiled by this process) for :func:`load`, atomically, unless
    the program has custom calls, and once a copy read back from the file has given
    ``outputs`` on ``leaves`` (the first run's), bit for bit; never an error (not kept: a
    later process lowers the program)."""
    file = path(where, key, device)
    if file is None:
        return
    try:
        if "custom_call" in exported.mlir_module():
            return
        import jax
        from jax.experimental.serialize_executable import serialize

        from .exported import _write

        _write(file, pickle.dumps(serialize(compiled), protocol=4), SUFFIX)
        copy = load(where, key, device)
        if copy is None or not _same(jax.block_until_ready(copy(*leaves)), list(outputs)):
            raise RuntimeError("its copy read back did not give the same outputs")
    except Exception as err:  # not serializable, a read-only cache, a copy that fails
        _log.debug("executable of program %s not kept (%s)", key, err)
        with contextlib.suppress(OSError):
            file.unlink(missing_ok=True)
            file.with_suffix(REFUSED).touch()
