"""JAX set-up shared by the library and the CLI: float64, vector width, the compilation cache.

:func:`configure` runs when ``jaxgeo`` is imported, before any submodule imports jax. When jax is
not yet imported it only sets environment variables (jax reads them when it starts, so
``jaxgeo --help`` stays free of jax); when it is, it updates ``jax.config``.

The compilation cache (XLA executables on disk, keyed by program, jax/jaxlib version, backend and
flags) makes every run after the first skip XLA compilation: ``jaxgeo demo`` compiles some sixty
small programs, each below jax's default thresholds (1 s of compile time), so the thresholds are
lowered to cache them all. Location: ``$JAXGEO_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxgeo/jax``
(``~/.cache/jaxgeo/jax``; ``~/Library/Caches`` on macOS, ``%LOCALAPPDATA%`` on Windows);
``JAXGEO_CACHE_DIR=off`` turns it off. A user's own ``JAX_COMPILATION_CACHE_DIR`` (or a
``jax_compilation_cache_dir`` set before jaxgeo is imported) is left as it is. A directory that
cannot be one (a file, under a file, not writable) turns the cache off, said once
(:func:`cache_problem`): a :class:`~jaxgeo.errors.JaxgeoWarning` when jaxgeo is imported, or
in the ``jaxgeo`` command a ``warning:`` line of its own (jax would warn at every program it
failed to cache, with a raw ``UserWarning``).

Several processes may share the cache: jax writes an entry with a plain ``write_bytes`` (a reader
could see half of it), so the size limit is set, which makes jax take a file lock
(``filelock``) around every read and write and evict least-recently-used entries beyond
``CACHE_MAX_BYTES``.

The CPU's cores: XLA runs a program on one device, and its intra-op threads share out that
program's operations; the many small operations of a batch of small problems
(``lsq.solve_batch``: 10 000 bias adjustments) then make the threads wait on each other at
every step (~500 thread switches per call of that batch on 2 cores, against ~70 with a device
per core), and they do not split further over more cores. jaxgeo therefore asks jax for one
CPU device per core this process may use (``jax_num_cpu_devices``: ``os.sched_getaffinity``,
so ``taskset -c 0`` gives one), and the batch paths shard their problems over the devices, each
running its own share (:func:`cpu_device_count`).
One device -- jax's own default -- where ``JAXGEO_CPU_DEVICES=1``, where the caller chose a
device count (``JAX_NUM_CPU_DEVICES``, ``--xla_force_host_platform_device_count``) or asked
XLA for a single thread (``--xla_cpu_multi_thread_eigen=false``, as the test suite does). One
program on one device (a single adjustment, a projection) runs as before.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

CACHE_ENV = "JAXGEO_CACHE_DIR"
"""Environment variable: the cache directory, or ``off``."""
MARK_ENV = "_JAXGEO_EXPORTED_JAX_CACHE_DIR"
"""Set beside the ``JAX_*`` cache variables jaxgeo exports for jax to read (the directory), so
that a child process can tell them from a user's own (:func:`_forget_inherited`)."""
CACHE_MAX_BYTES = 2 * 1024**3
"""Least-recently-used entries beyond this total size are evicted (jax's LRU cache)."""
MIN_COMPILE_TIME_S = 0.0
"""Cache every program, however fast it compiled (jax's default: 1 s)."""
MIN_ENTRY_BYTES = 0
"""Cache every program, however small (jax's default: 0; set explicitly)."""
VECTOR_FLAG = "--xla_cpu_prefer_vector_width=512"
"""XLA flag added to ``XLA_FLAGS`` unless the user's own set ``xla_cpu_prefer_vector_width``:
XLA's CPU code uses 256-bit vectors by default even where the CPU has 512-bit ones (AVX-512); a
1e6-point RPC projection takes 1.6 ms with it against 2.1 ms without (2-core AVX-512 CPU, same
results to the bit). Ignored on CPUs without AVX-512 and on other backends; jax reads it when
its CPU backend starts, so it has no effect in a process that used jax before importing jaxgeo."""


DEVICES_ENV = "JAXGEO_CPU_DEVICES"
"""Environment variable: the number of CPU devices jaxgeo asks jax for (default: the usable
cores; ``1``: jax's single device)."""
DEVICES_MARK_ENV = "_JAXGEO_EXPORTED_NUM_CPU_DEVICES"
"""Set beside the ``JAX_NUM_CPU_DEVICES`` jaxgeo exports, so that a child process (another
affinity: ``taskset``) counts its own cores instead of inheriting its parent's number."""
SINGLE_THREAD_FLAG = "xla_cpu_multi_thread_eigen=false"
"""An ``XLA_FLAGS`` entry that asks XLA's CPU backend for one thread: then one device too."""


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # no CPU affinity on this OS (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def cpu_device_count() -> int:
    """The CPU devices jaxgeo asks for: ``$JAXGEO_CPU_DEVICES`` (an integer >= 1; anything
    else counts as 1), else :func:`usable_cores`; 1 where the caller chose the device count or
    a single thread (see the module docstring)."""
    value = os.environ.get(DEVICES_ENV, "").strip()
    if value:
        try:
            return max(1, int(value))
        except ValueError:
            return 1
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" in flags or SINGLE_THREAD_FLAG in flags:
        return 1
    return usable_cores()


def _cpu_devices(jax) -> None:
    """Ask jax for :func:`cpu_device_count` CPU devices, unless the caller set a count."""
    mark = os.environ.pop(DEVICES_MARK_ENV, None)
    if mark is not None and os.environ.get("JAX_NUM_CPU_DEVICES") == mark:
        os.environ.pop("JAX_NUM_CPU_DEVICES")  # a parent jaxgeo's number, not the caller's
    if "JAX_NUM_CPU_DEVICES" in os.environ or "xla_force_host_platform_device_count" in (
        os.environ.get("XLA_FLAGS", "")
    ):
        return
    n = cpu_device_count()
    if n < 2:
        return
    if jax is None:
        os.environ["JAX_NUM_CPU_DEVICES"] = os.environ[DEVICES_MARK_ENV] = str(n)
        return
    try:  # refused once jax has started its backends: one device then, as jax's default
        if jax.config.jax_num_cpu_devices < 0:
            jax.config.update("jax_num_cpu_devices", n)
    except Exception:  # noqa: BLE001 - jax raises a RuntimeError; any refusal means "leave it"
        pass


def default_cache_dir() -> Path:
    """The per-user cache directory for compiled programs (see the module docstring)."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA", Path.home() / "AppData" / "Local"))
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "jaxgeo" / "jax"


def cache_dir() -> Path | None:
    """The cache directory in effect for jaxgeo, ``None`` when ``JAXGEO_CACHE_DIR=off`` or when
    the directory cannot be one (:func:`cache_problem`)."""
    value = os.environ.get(CACHE_ENV, "").strip()
    if value.lower() in ("off", "0", "none", "false", "no"):
        return None
    path = Path(value).expanduser() if value else default_cache_dir()
    return None if _unusable(path) else path


def _unusable(path: Path) -> str | None:
    """Why ``path`` cannot be the cache directory (``None``: it can; made when first used)."""
    if path.exists():
        if not path.is_dir():
            return "is not a folder"
        return None if os.access(path, os.W_OK | os.X_OK) else "is not writable"
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        return f"cannot be made: {parent} is not a folder"
    return None if os.access(parent, os.W_OK | os.X_OK) else f"cannot be made in {parent}"


def cache_problem() -> str | None:
    """Why the compilation cache is off although it was asked for (a sentence naming the
    directory and :data:`CACHE_ENV`), or ``None``."""
    value = os.environ.get(CACHE_ENV, "").strip()
    if value.lower() in ("off", "0", "none", "false", "no"):
        return None
    path = Path(value).expanduser() if value else default_cache_dir()
    why = _unusable(path)
    if why is None:
        return None
    named = f"{CACHE_ENV}={value}" if value else f"the compilation cache {path}"
    return (f"{named}: {why}; compiled programs are not cached (set {CACHE_ENV} to a writable "
            "folder, or to off)")  # fmt: skip


def _the_command() -> bool:
    """Whether this process is the ``jaxgeo`` command (which says a cache problem as its own
    line): its script, or ``python -m jaxgeo.cli`` (``-m`` while the package is imported)."""
    first = sys.argv[0] if sys.argv else ""
    return first == "-m" or os.path.basename(first) in ("jaxgeo", "jaxgeo.exe")


def _settings(path: Path) -> dict[str, object]:
    settings: dict[str, object] = {
        "jax_compilation_cache_dir": str(path),
        "jax_persistent_cache_min_compile_time_secs": MIN_COMPILE_TIME_S,
        "jax_persistent_cache_min_entry_size_bytes": MIN_ENTRY_BYTES,
    }
    try:  # the file lock that makes a shared cache safe needs filelock
        import filelock  # noqa: F401

        settings["jax_compilation_cache_max_size"] = CACHE_MAX_BYTES
    except ImportError:  # pragma: no cover - filelock is a dependency
        pass
    return settings


def _forget_inherited() -> None:
    """Drop the cache variables a parent jaxgeo process exported (a child inherits them, and
    would otherwise take the parent's cache for the user's own and ignore its own
    ``JAXGEO_CACHE_DIR``, ``off`` included); a user's own ``JAX_COMPILATION_CACHE_DIR`` stays."""
    mark = os.environ.get(MARK_ENV)
    if mark is None:
        return
    if os.environ.get("JAX_COMPILATION_CACHE_DIR") == mark:
        for name in _settings(Path(mark)):
            os.environ.pop(name.upper(), None)
    os.environ.pop(MARK_ENV, None)


def _vector_width() -> None:
    """Add :data:`VECTOR_FLAG` to ``XLA_FLAGS`` unless the user's flags set the width."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_prefer_vector_width" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {VECTOR_FLAG}".strip()


def configure(warning: type[Warning] = UserWarning) -> None:
    """float64 on; 512-bit vectors for XLA's CPU code; one CPU device per usable core; the
    persistent compilation cache on (unless off or set by the user; a directory that cannot be
    one is said as a ``warning``, except in the ``jaxgeo`` command, which says it itself)."""
    _vector_width()
    jax = sys.modules.get("jax")
    _cpu_devices(jax)
    if jax is None:
        _forget_inherited()
        os.environ["JAX_ENABLE_X64"] = "1"
    else:
        jax.config.update("jax_enable_x64", True)
    path = cache_dir()
    if path is None:
        problem = cache_problem()
        if problem and not _the_command():
            import warnings

            warnings.warn(problem, warning, stacklevel=3)
        return
    if jax is None:
        if "JAX_COMPILATION_CACHE_DIR" in os.environ:
            return
        for name, value in _settings(path).items():
            os.environ.setdefault(name.upper(), str(value))
        os.environ[MARK_ENV] = str(path)
    else:
        if jax.config.jax_compilation_cache_dir is not None:
            return
        for name, value in _settings(path).items():
            jax.config.update(name, value)
