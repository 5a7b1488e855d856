"""Compiled executables kept beside the exported programs (:mod:`.exported`), on a CPU.

A kept program (a serialized ``jax.export`` program) spares a warm process the trace; running
it still took its lowering (``jax.jit`` of the exported call: a few tens of ms a program) and,
at the first lowering of a process, jax's LAPACK set-up, which imports ``scipy.linalg`` (0.25 s
of every warm ``jaxgeo ortho``, whose programs call no LAPACK kernel), then a look-up in the
compilation cache. :func:`keep` writes the executable itself
(:func:`jax.experimental.serialize_executable.serialize`) beside the program once it is
compiled; :func:`load` gives it back to a later process, which runs it at once.

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
from pathlib import Path

SUFFIX = ".xlaexe"

_log = logging.getLogger(__name__)


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
    except Exception as err:  # a damaged or foreign file: compiled again, rewritten
        _log.debug("kept executable %s unreadable (%s): compiling again", file, err)
        return None
    with contextlib.suppress(OSError):  # recently used (a read-only cache stays as it is)
        os.utime(file)
    return compiled


def keep(where: Path | None, key: str, device, compiled, exported) -> None:
    """Write ``compiled`` (the ``jax.stages.Compiled`` of the exported program ``exported``,
    key ``key``, on ``device``) for :func:`load`, atomically, unless the program has custom
    calls; never an error (not kept: a later process lowers the program)."""
    file = path(where, key, device)
    if file is None:
        return
    try:
        if "custom_call" in exported.mlir_module():
            return
        from jax.experimental.serialize_executable import serialize

        from .exported import _write

        _write(file, pickle.dumps(serialize(compiled), protocol=4), SUFFIX)
    except Exception as err:  # not serializable, a read-only cache
        _log.debug("executable of program %s not kept (%s)", key, err)
