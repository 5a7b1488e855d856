"""The timing harness every study shares: warm-up, best of N, same-run ratios, the machine.

Timing (:func:`best_of`): one warm-up call (compilation, caches, page faults; its time is kept
as ``first_s``), then ``repeats`` calls, each waited on (:func:`wait`: ``jax.block_until_ready``
on the jax arrays it returns; numpy results are complete when returned), and the best wall time
kept: on a shared machine the best run is the one least disturbed. Small calls get more
repeats (:func:`repeats_for`, the same rule for every implementation of one size). Ratios
(:func:`ratio_vs`) are of times measured in the same run: a peer's time over jaxgeo's, > 1
where jaxgeo is faster.

Every study prints one JSON object, the ``machine`` it ran on included (:func:`emit`,
:func:`machine`: CPU model, cores, load, jax / jaxlib / jaxgeo versions, devices, date and the
command). A run kept is saved as ``benchmarks/results/<study>-<case>-<machine>.json``
(:func:`result_name`): ``study`` the module (``projection``), ``case`` the sizes or variant
measured (``1e2to1e7``, ``10k_l2``; no ``-``), ``machine`` ``<cores>core-<backend>``, with
``-loaded`` appended when other work held the machine.
"""

from __future__ import annotations

import dataclasses
import datetime
import importlib.metadata
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np

SMALL_WORK = 100_000
"""Points timed per size at least (up to 1000 calls): a 100-point call takes ~0.2 ms, and the
best of 3 such calls on a shared machine measures the noise, not the call."""

RESULT_NAME = re.compile(
    r"^(?P<study>[a-z0-9_]+)-(?P<case>[A-Za-z0-9_.]+)-(?P<machine>\d+core-[a-z]+(?:-[a-z]+)*)\.json$"
)
"""``<study>-<case>-<machine>.json``: see the module docstring."""


def repeats_for(n: int, repeats: int) -> int:
    """Timed calls for ``n`` points: ``repeats``, or more for small ``n`` (every
    implementation of one size gets the same rule)."""
    return max(repeats, min(1000, SMALL_WORK // max(n, 1)))


def wait(out):
    """``out``, computed: jax arrays in it are waited on (``jax.block_until_ready``); numpy
    arrays and Python numbers are returned at once (nothing to wait for, nothing timed)."""
    if out is None or isinstance(out, np.ndarray | float | int | str):
        return out
    jax = sys.modules.get("jax")  # a study that never imported jax has no jax arrays
    return out if jax is None else jax.block_until_ready(out)


@dataclasses.dataclass(frozen=True)
class Timing:
    """What :func:`best_of` measured (seconds)."""

    best_s: float
    """The best of the timed calls (``inf`` when none was timed)."""
    first_s: float
    """The first warm-up call: compilation included for a jitted function."""
    runs_s: tuple[float, ...]
    """Every timed call, in order."""
    out: object
    """The last call's output."""


def best_of(fn: Callable[[], object], repeats: int, warmup: int = 1) -> Timing:
    """``warmup`` calls of ``fn`` (at least one), then the best wall time of ``repeats`` calls,
    each waited on (:func:`wait`)."""
    t0 = time.perf_counter()
    out = wait(fn())
    first = time.perf_counter() - t0
    for _ in range(warmup - 1):
        out = wait(fn())
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = wait(fn())
        runs.append(time.perf_counter() - t0)
    return Timing(min(runs, default=np.inf), first, tuple(runs), out)


def best_time(fn: Callable[[], object], repeats: int) -> tuple[float, object]:
    """``(best wall time, last output)`` of :func:`best_of` with one warm-up call."""
    timing = best_of(fn, repeats)
    return timing.best_s, timing.out


def ratio_vs(ours_s: float, peers_s: dict[str, float]) -> dict[str, float]:
    """``{"ratio_vs_<peer>": peer's time / ours}`` for times of the same run: > 1 where jaxgeo
    is faster."""
    return {f"ratio_vs_{name}": t / ours_s for name, t in peers_s.items()}


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``, macOS' sysctl), else the architecture."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    if sys.platform == "darwin":
        try:
            return subprocess.run(
                ["sysctl", "-n", "machdep.cpu.brand_string"], capture_output=True, text=True,
                check=True,
            ).stdout.strip()  # fmt: skip
        except (OSError, subprocess.CalledProcessError):
            pass
    return platform.processor() or platform.machine()


def command() -> str:
    """The command line that is running, as ``python -m benchmarks....`` when run that way."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    name = getattr(spec, "name", None)
    prog = f"python -m {name}" if name and name != "__main__" else f"python {sys.argv[0]}"
    return " ".join([prog, *map(shlex.quote, sys.argv[1:])])


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def machine() -> dict:
    """The machine and software a result was measured on, now: CPU model, architecture, cores
    (and those this process may use), load average, OS, Python, jax / jaxlib / jaxgeo versions,
    jax's backend and devices (when the study imported jax), the date (UTC) and the command."""
    cores = os.cpu_count()
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else cores
    out = {
        "cpu": cpu_model(),
        "arch": platform.machine(),
        "cores": cores,
        "cores_usable": usable,
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "os": platform.platform(),
        "python": platform.python_version(),
        "jax": _version("jax"),
        "jaxlib": _version("jaxlib"),
        "jaxgeo": _version("jaxgeo"),
    }
    jax = sys.modules.get("jax")
    if jax is not None:
        out["backend"] = jax.default_backend()
        out["devices"] = [str(d) for d in jax.devices()]
    out["date"] = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    out["command"] = command()
    return out


def machine_label(m: dict) -> str:
    """The ``<machine>`` part of a result's name: ``<cores>core-<backend>`` (``2core-cpu``)."""
    return f"{m.get('cores_usable') or m['cores']}core-{m.get('backend', 'cpu')}"


def result_name(study: str, case: str, m: dict | None = None, loaded: bool = False) -> str:
    """``<study>-<case>-<machine>.json`` for a run of ``study`` on ``m`` (default: this one)."""
    label = machine_label(machine() if m is None else m) + ("-loaded" if loaded else "")
    name = f"{study}-{case}-{label}.json"
    if not RESULT_NAME.match(name):
        raise ValueError(f"{name!r} does not follow <study>-<case>-<machine>.json (no '-' in case)")
    return name


def emit(result: dict, indent: int | None = 1, **dumps) -> dict:
    """Print ``result`` as one JSON object on stdout, with the ``machine`` it ran on last;
    return it. ``dumps``: further ``json.dumps`` arguments (e.g. ``default=str``)."""
    out = {**result, "machine": machine()}
    print(json.dumps(out, indent=indent, **dumps), flush=True)
    return out
