"""Numpy in and out of a compiled kernel without copies (CPU backend).

A numpy call of a kernel costs more than the kernel when jaxlib copies the input (it does unless
the data start on a 64-byte boundary: numpy's own arrays start on 16) and numpy copies the
output (``np.asarray`` of a jax array is read-only; a copy into a fresh array pays a page fault
per 4 KiB). :func:`call_exact` avoids both for float64, C-contiguous inputs:

- **in**: the kernel gets a flat, read-only view of each input's memory that starts on the
  64-byte boundary at or before its first element (:func:`aligned_flat`), and the offset of that
  element (0-7), which jaxlib uses in place. The view reads up to 56 bytes before the input;
  they lie in the same 64-byte line, hence the same memory page, and are never used;
- **out**: the kernel's fresh output is returned as a writable numpy array over its own memory
  (:func:`writable`), which the returned array alone references.

The program is compiled for the exact shapes and offsets, so a size gets one only once it is
used a second time (:data:`SEEN_MAX`, :data:`PROGRAMS_MAX`): a one-off call of a new size
keeps the bucketed, chunked path of :mod:`._rpc_eval` (a few programs for all sizes), a
repeated size (tiles of one raster, a loop over epochs) runs whole, in one call.

Measured (2-core AVX-512 CPU, 1e6 points, the Pleiades RPC, ``benchmarks/speed/projection.py``):
``rpc.project(numpy)`` 5.1 ms chunked (a size used once), 1.7 ms here (173x GDAL); a size's
second use compiles for ~0.13 s (~0.05 s from the persistent compilation cache).
"""

from __future__ import annotations

import collections
import functools
import math
import threading
from collections.abc import Callable

import jax
import numpy as np

ALIGN = 64
"""Bytes: jaxlib's CPU client uses host memory aligned to this in place instead of copying."""
EXACT_MIN = 1 << 18
"""Points: smaller calls stay on the chunked path (their copies cost little)."""
SEEN_MAX = 64
"""Call keys remembered to tell a size's second use (least recently used forgotten)."""
PROGRAMS_MAX = 8
"""Size-specific programs kept (least recently used dropped: bounded memory)."""


def runs_on_cpu() -> bool:
    """True when arrays not placed on a device (numpy inputs) are computed on a CPU here."""
    device = jax.config.jax_default_device
    if device is None:
        return jax.default_backend() == "cpu"
    return (device if isinstance(device, str) else device.platform) == "cpu"


def host_device():
    """This process's first CPU device (jax always has one, beside any GPU)."""
    return jax.local_devices(backend="cpu")[0]


class _Memory:
    """``__array_interface__`` over raw float64 memory, keeping ``owner`` alive."""

    def __init__(self, address: int, shape: tuple[int, ...], readonly: bool, owner: object):
        self.__array_interface__ = {
            "data": (address, readonly),
            "shape": shape,
            "typestr": "<f8",
            "version": 3,
        }
        self.owner = owner


def eligible(a: np.ndarray) -> bool:
    """True when ``a`` can be read in place: float64, C-contiguous, element-aligned."""
    return (
        a.dtype == np.float64
        and a.flags.c_contiguous
        and a.size > 0
        and a.ctypes.data % a.itemsize == 0
    )


def aligned_flat(a: np.ndarray) -> tuple[np.ndarray, int]:
    """A read-only flat float64 view of ``a``'s memory from the :data:`ALIGN`-byte boundary at or
    before its first element, and that element's offset in the view (0-7 elements)."""
    if not eligible(a):
        raise ValueError("aligned_flat needs a float64, C-contiguous, element-aligned array")
    offset = (a.ctypes.data % ALIGN) // a.itemsize
    start = a.ctypes.data - offset * a.itemsize
    return np.asarray(_Memory(start, (a.size + offset,), True, a)), offset


def writable(x: jax.Array) -> np.ndarray:
    """``x`` (a CPU array nobody else references) as a writable numpy array over its memory,
    which keeps ``x`` alive (``x.delete()``, e.g. over ``jax.live_arrays()``, would free it
    under the numpy array: the one way to break it)."""
    if any(d.platform != "cpu" for d in x.devices()):  # a device pointer: numpy would crash
        raise ValueError("writable needs an array in the CPU's memory")
    x.block_until_ready()
    return np.asarray(_Memory(x.unsafe_buffer_pointer(), tuple(x.shape), False, x))


class Recent:
    """A dictionary of the last ``limit`` keys used (least recently used forgotten)."""

    def __init__(self, limit: int):
        self.limit = limit
        self._items: collections.OrderedDict = collections.OrderedDict()
        self._lock = threading.Lock()

    def get(self, key):
        with self._lock:
            if key not in self._items:
                return None
            self._items.move_to_end(key)
            return self._items[key]

    def put(self, key, value) -> None:
        with self._lock:
            self._items[key] = value
            self._items.move_to_end(key)
            while len(self._items) > self.limit:
                self._items.popitem(last=False)

    def __len__(self) -> int:
        return len(self._items)


_SEEN = Recent(SEEN_MAX)
_PROGRAMS = Recent(PROGRAMS_MAX)
_ON_HOST = Recent(PROGRAMS_MAX)


def on_host(leaves: list) -> list:
    """A model's arrays ``leaves`` on :func:`host_device`: those already there as they are, the
    others put there once per model (its last :data:`PROGRAMS_MAX` kept, by the arrays'
    identity). On a GPU machine a numpy projection computes on the host with a model made on
    the GPU: without this every call would copy its arrays back from the GPU first."""
    host = host_device()
    placed = [not isinstance(x, jax.Array) or x.devices() == {host} for x in leaves]
    if all(placed):
        return leaves
    key = tuple(map(id, leaves))
    hit = _ON_HOST.get(key)
    if hit is not None and all(a is b for a, b in zip(hit[0], leaves, strict=True)):
        return hit[1]
    moved = [x if ok else jax.device_put(x, host) for x, ok in zip(leaves, placed, strict=True)]
    _ON_HOST.put(key, (list(leaves), moved))  # holds the originals: their ids stay theirs
    return moved


@functools.partial(jax.jit, static_argnums=(0, 1, 4))
def _exact_kernel(body, treedef, leaves, flats, layout):
    arrays = [f[o : o + math.prod(s)].reshape(s) for f, (o, s) in zip(flats, layout, strict=True)]
    return body(treedef, leaves, *arrays)


def call_exact(
    body: Callable, treedef, leaves, arrays: tuple[np.ndarray, ...], n: int
) -> np.ndarray | None:
    """``body(treedef, leaves, *arrays)`` compiled for these exact shapes, with the inputs used in
    place and the output returned without a copy; ``None`` (the caller takes its chunked path)
    when the computation would not run on a CPU, ``n`` is below :data:`EXACT_MIN`, an input is not
    :func:`eligible`, or this call's key (kernel, shapes, offsets) is new. The last
    :data:`PROGRAMS_MAX` programs are kept (compiled ahead of time, outside jit's cache)."""
    if n < EXACT_MIN or not runs_on_cpu() or not all(map(eligible, arrays)):
        return None
    views = [aligned_flat(a) for a in arrays]
    flats = tuple(v for v, _ in views)
    layout = tuple((offset, a.shape) for (_, offset), a in zip(views, arrays, strict=True))
    key = (body, treedef, layout, tuple((x.shape, x.dtype) for x in leaves))
    program = _PROGRAMS.get(key)
    if program is None:
        if _SEEN.get(key) is None:
            _SEEN.put(key, True)
            return None
        program = _exact_kernel.lower(body, treedef, leaves, flats, layout).compile()
        _PROGRAMS.put(key, program)
    return writable(program(leaves, flats))
