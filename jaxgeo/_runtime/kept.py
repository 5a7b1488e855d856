"""Kept programs, declared where a pure function is defined: how it compiles is decided here.

A module of geometry or workflow marks a pure JAX function once, at its definition, and its
callers call it like any function; which program runs, and how XLA compiles it, is this
module's decision (on :mod:`.exported`'s machinery):

- :func:`kept`: a function of concrete inputs runs as a kept program (:func:`.exported.call`):
  traced at most once per input structure across runs (a warm process traces nothing), small
  programs compiled quickly, large inputs compiled apart.
- :func:`kept_points`: a kernel over points (a model's projection or localisation of ``n``
  points), run over fixed-size chunks: at most two programs whatever ``n``, the small chunk
  compiled quickly (a refit grid, GCPs), the large one for speed (many points).
- :func:`kept_kernel`: a kernel over a whole tile of pixels (an orthoimage's positions and
  resampling): one program per tile shape, kept whatever its size (a warm run traces nothing),
  compiled for speed.
- :func:`kept_solve`: a solve, kept as one program, or as two (its iterations, then what
  follows them) where its inputs are too large for one to compile in little memory; compiled
  with :data:`.exported.SOLVE_COMPILE` unless small.
- :func:`beside_solve`: host work run on another thread from the moment a solve is traced
  (tracing holds the GIL, XLA's compilation and runs release it).

Within a transformation (tracers among the inputs: ``jit``, ``vmap``, ``grad`` of a caller) a
kept function is the jitted function (``eqx.filter_jit``), which jax inlines into the
enclosing program: what :func:`.exported.call` does.

A kept program's key (:mod:`.program_key`) is that of the function as defined -- its module,
qualified name and source -- never that of the wrapper made here: the same function keeps its
key (and its programs on disk) with or without the decorator, and two functions never share
one.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import functools
import threading
from collections.abc import Callable, Iterator
from typing import Any

import jax
import numpy as np

from . import exported


def _traced(args, kwargs) -> bool:
    """Whether a tracer is among the inputs (a call inside a caller's transformation)."""
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves((args, kwargs)))


def kept(fn: Callable) -> Callable:
    """Decorator: ``fn`` (a module-level pure JAX function) run as a kept program
    (:func:`.exported.call`): the result of ``eqx.filter_jit(fn)``, traced at most once per
    input structure across processes. ``__wrapped__`` is ``fn``, whose identity keys the
    program."""

    @functools.wraps(fn)
    def program(*args, **kwargs):
        return exported.call(fn, *args, **kwargs)

    return program


def kept_kernel(fn: Callable) -> Callable:
    """Decorator of a kernel over a tile of pixels (a module-level pure JAX function whose
    inputs have the tile's fixed, padded shapes): run as a kept program compiled with XLA's
    defaults and kept whatever its size (:func:`.exported.call_kernel`), where :func:`kept`
    would compile a tile of over a million values apart and trace it again in every process.
    ``__wrapped__`` is ``fn``."""

    @functools.wraps(fn)
    def program(*args, **kwargs):
        return exported.call_kernel(fn, *args, **kwargs)

    return program


def kept_points(chunks: int | tuple[int, int], fixed: int = 1) -> Callable[[Callable], Callable]:
    """Decorator of a kernel over points: ``fn(*head, *points)`` with ``fixed`` leading
    arguments passed whole (a model, a DEM) and point arrays whose first axes have one length
    ``n``, each point's result independent of the others'.

    The decorated function takes any ``n`` and returns ``fn``'s result for all ``n`` points
    (numpy, ``n`` rows): the points are run in chunks of ``chunks[0]`` points below
    ``chunks[1]`` points, compiled quickly (small programs: their run takes little, their
    compilation most), and of ``chunks[1]`` points from there on, compiled with XLA's defaults
    (:func:`.exported.call_kernel`: the run of many chunks matters more than one compilation);
    one size ``chunks`` (an int): chunks of that size, compiled quickly unless large
    (:func:`.exported.call`). The last chunk is padded by repeating the last point (zeros when
    there are none), the padding's results cut off. At most two programs per structure of the
    fixed arguments, whatever ``n``. Within a transformation: ``fn`` on all the points at once,
    jitted."""
    small, large = (chunks, None) if isinstance(chunks, int) else (int(c) for c in chunks)

    def decorate(fn: Callable) -> Callable:
        @functools.wraps(fn)
        def program(*args):
            if _traced(args, {}):
                return exported.call(fn, *args)
            head, points = args[:fixed], [np.asarray(p) for p in args[fixed:]]
            n = len(points[0])
            if large is None or n < large:
                chunk, call = small, exported.call
            else:
                chunk, call = large, exported.call_kernel
            n_pad = -(-max(n, 1) // chunk) * chunk
            mode = "edge" if n else "constant"  # no points: one chunk of zeros, its results cut
            padded = [np.pad(p, [(0, n_pad - n)] + [(0, 0)] * (p.ndim - 1), mode=mode)
                      for p in points]  # fmt: skip
            out = [jax.tree.map(np.asarray, call(fn, *head, *(p[i : i + chunk] for p in padded)))
                   for i in range(0, n_pad, chunk)]  # fmt: skip
            return jax.tree.map(lambda *parts: np.concatenate(parts)[:n], *out)

        return program

    return decorate


def kept_solve(whole: Callable, *, parts: tuple[Callable, Callable]) -> Callable:
    """A solve as a kept program: ``whole(*args, **kwargs)``, or where its inputs are too large
    for one exported program (compiled apart: over :data:`.exported.MAX_ELEMENTS` array
    elements) the same solve as two programs, ``first, finish = parts``:
    ``finish(*args, first(*args, **kwargs), **kwargs)``, whose compilations each need less
    memory than the whole's (the second is compiled once the first's outputs are computed, so
    that the first's working memory is not held through that compilation). Compiled with
    :data:`.exported.SOLVE_COMPILE` unless small enough for :data:`.exported.QUICK_COMPILE`;
    :func:`beside_solve`'s work starts once it is traced. Within a transformation: ``whole``,
    jitted."""
    first, finish = parts

    @functools.wraps(whole)
    def solve(*args, **kwargs):
        if _traced(args, kwargs) or not exported.compiled_apart(*args, **kwargs):
            return exported.call_solve(whole, *args, **kwargs)
        done = exported.call_solve(first, *args, **kwargs)
        return exported.call_solve(finish, *args, done, **kwargs)

    return solve


@contextlib.contextmanager
def beside_solve(
    work: Callable[..., Any] | None, *args, **kwargs
) -> Iterator[concurrent.futures.Future]:
    """``work(*args, **kwargs)`` on another thread beside this block, started once a solve
    (:func:`kept_solve`) run in this block, in this thread, has been traced -- before XLA
    compiles (or, warm, runs) it -- or else once the block ends: work started then does not
    compete with the trace for the GIL, and XLA's compilation and runs release it (``jaxgeo
    demo`` cold: the direct georeferencing traced beside the solve's trace delayed it by ~1 s
    on 2 cores). Yields a future of its result, done when the block has been left; ``None``
    for no ``work``. Where the block raises, the work is not run (its result ``None``) and the
    block's error goes on."""
    if work is None:
        nothing: concurrent.futures.Future = concurrent.futures.Future()
        nothing.set_result(None)
        yield nothing
        return
    go, abandon = threading.Event(), threading.Event()

    def after_trace():
        go.wait()
        return None if abandon.is_set() else work(*args, **kwargs)

    with concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="beside-solve") as pool:
        future = pool.submit(after_trace)
        try:
            with exported.when_solve_traced(go.set):
                yield future
        except BaseException:
            abandon.set()
            raise
        finally:
            go.set()
