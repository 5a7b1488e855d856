"""The key of a kept program (:mod:`._exported`): a SHA-256 of everything its trace depends on.

jaxgeo's source, that of any module outside jaxgeo that defines the function or a class of the
inputs (a user's own sensor model), the versions of Python and of the libraries traced into the
program, the ``jax.config`` options and environment variables that change a trace, the backend,
the input structure with its static values pickled, and each array's shape and dtype.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import os
import pickle
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import jax

TRACED_BY = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "jaxtyping", "numpy")
"""Distributions whose versions are part of the key (their code is traced into the programs)."""
OWN_CODE = frozenset({"jaxgeo", *TRACED_BY, "builtins", "collections", "abc", "typing"})
"""Top-level modules whose code the key holds already (jaxgeo's source, the versions of
:data:`TRACED_BY`) or Python's own: a class or function from anywhere else has its module's
source in the key (:func:`foreign_digest`)."""
JAX_OPTIONS = (
    "jax_enable_x64",
    "jax_default_matmul_precision",
    "jax_numpy_dtype_promotion",
    "jax_numpy_rank_promotion",
    "jax_default_prng_impl",
)
"""``jax.config`` options that change what a trace produces (part of the key)."""
ENVIRONMENT = ("EQX_ON_ERROR", "JAXGEO_TYPECHECK")
"""Environment variables read while tracing (part of the key)."""


@functools.cache
def _source_digest() -> str:
    """SHA-256 of every jaxgeo module's source (computed once per process, a few ms)."""
    root = Path(__file__).resolve().parent.parent  # the jaxgeo package
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


@functools.cache
def _versions() -> tuple[str, ...]:
    """Versions of everything that shapes a traced program besides jaxgeo's own source."""
    from importlib.metadata import PackageNotFoundError, version

    out = [sys.version]
    for dist in TRACED_BY:
        try:
            out.append(f"{dist}=={version(dist)}")
        except PackageNotFoundError:
            out.append(f"{dist}: none")
    return tuple(out)


def _node_types(treedef) -> Iterator[type]:
    data = treedef.node_data()
    if data is not None:
        yield data[0]
    for child in treedef.children():
        yield from _node_types(child)


def foreign_digest(fn: Callable, treedef) -> str:
    """SHA-256 of the source of every module outside :data:`OWN_CODE` that defines ``fn`` or a
    class of the input structure, or one of its bases (a user's own sensor model): that code is
    traced into the program, so an edit must give another key. Raises (``OSError``,
    ``TypeError``) where such a module has no source file (a class defined in a notebook or at
    the prompt): no stable key, plain jit then."""
    try:
        names = _foreign_modules(fn, treedef)
    except TypeError:  # an unhashable structure: walked every time
        names = _foreign_modules.__wrapped__(fn, treedef)
    h = hashlib.sha256()
    for name in names:
        h.update(name.encode())
        h.update(_module_digest(inspect.getsourcefile(sys.modules[name])).encode())
    return h.hexdigest()


@functools.lru_cache(maxsize=1024)
def _foreign_modules(fn: Callable, treedef) -> tuple[str, ...]:
    """The modules outside :data:`OWN_CODE` of :func:`foreign_digest`, sorted (kept per
    function and structure: walking the structure's classes took 20 us a call)."""
    names = {fn.__module__}
    names.update(base.__module__ for t in _node_types(treedef) for base in t.__mro__)
    return tuple(sorted(n for n in names if n.split(".")[0] not in OWN_CODE))


def _module_digest(path: str | None) -> str:
    """SHA-256 of a source file, kept per path, size and modification time."""
    if path is None:
        raise OSError("no source file")
    stat = os.stat(path)
    return _file_digest(path, stat.st_size, stat.st_mtime_ns)


@functools.lru_cache(maxsize=256)
def _file_digest(path: str, size: int, mtime_ns: int) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@functools.lru_cache(maxsize=64)
def _dtype_name(dtype) -> str:
    return str(dtype)  # numpy's takes 9 us


def key(fn: Callable, treedef, static, leaves) -> str:
    """The key of ``fn`` on inputs of this structure (``treedef``), static values and leaves."""
    h = hashlib.sha256()
    config = {name: getattr(jax.config, name, None) for name in JAX_OPTIONS}
    parts = (
        fn.__module__,
        fn.__qualname__,
        _source_digest(),
        foreign_digest(fn, treedef),
        _versions(),
        tuple(sorted(config.items())),
        tuple((name, os.environ.get(name)) for name in ENVIRONMENT),
        jax.default_backend(),
        tuple(
            (tuple(x.shape), _dtype_name(x.dtype), bool(getattr(x, "weak_type", False)))
            for x in leaves
        ),
    )
    h.update(repr(parts).encode())
    h.update(pickle.dumps((treedef, static), protocol=4))
    return h.hexdigest()
