"""The runtime type checker of the test suite: beartype behind jaxtyping, lenient on sequences.

jaxgeo's public functions take array-likes (``Float[ArrayLike, "*batch 3"]``), and users pass
plain lists as often as arrays: ``rpc.project([[lon, lat, h]])``. jax's ``ArrayLike`` excludes
lists, so a parameter annotated with a jaxtyping array type also accepts a ``Sequence`` here
(its shape is then checked where it becomes an array); so does a plain ``np.ndarray`` or
``jax.Array`` parameter. Everything else is checked as annotated:
array shapes and dtypes, and ints for floats (PEP 484's numeric tower). ``Literal`` choices are
checked as their type only: the library names a bad choice itself, and tests assert its message.
"""

from __future__ import annotations

import functools
import typing
from collections.abc import Sequence

import beartype
import jax
import jaxtyping
import numpy as np

_CONF = beartype.BeartypeConf(is_pep484_tower=True)


def _is_array_hint(hint) -> bool:
    return isinstance(hint, type) and issubclass(
        hint, (jaxtyping.AbstractArray, np.ndarray, jax.Array)
    )


def _with_numpy(hint):
    """``Float[Array, s]`` -> also ``Float[np.ndarray, s]`` (jnp functions take numpy arrays)."""
    if isinstance(hint, type) and issubclass(hint, jaxtyping.AbstractArray):
        if hint.array_type is jax.Array:
            return typing.Union[hint, hint.dtype[np.ndarray, hint.dim_str]]  # noqa: UP007
    return hint


def _lenient(hint):
    if typing.get_origin(hint) is typing.Literal:
        # the library validates its choices itself, with a message naming the value and the
        # choices (tested); the checker would pre-empt that message
        return typing.Union[tuple({type(a) for a in typing.get_args(hint)})]  # noqa: UP007
    if _is_array_hint(hint):
        return typing.Union[_with_numpy(hint), Sequence]  # noqa: UP007
    if typing.get_origin(hint) in (typing.Union, __import__("types").UnionType):
        args = typing.get_args(hint)
        if any(_is_array_hint(a) for a in args):
            return typing.Union[(*(_with_numpy(a) for a in args), Sequence)]  # noqa: UP007
    return hint


def typechecker(fn):
    """``beartype`` of ``fn`` with array-typed parameters also accepting sequences."""
    try:
        hints = typing.get_type_hints(fn, include_extras=True)
    except Exception:  # unresolvable annotations: check as beartype would
        return beartype.beartype(conf=_CONF)(fn)
    new = {k: (v if k == "return" else _lenient(v)) for k, v in hints.items()}
    if new == hints:
        return beartype.beartype(conf=_CONF)(fn)

    @functools.wraps(fn)
    def proxy(*args, **kwargs):
        return fn(*args, **kwargs)

    proxy.__annotations__ = new
    return beartype.beartype(conf=_CONF)(proxy)


def unchecked(fn):
    """``fn`` without the checker's wrapper, to test the library's own messages for input the
    annotations exclude (e.g. a wrong last axis)."""
    return getattr(fn, "__wrapped__", fn)
