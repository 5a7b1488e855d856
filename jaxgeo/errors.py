"""Base classes of jaxgeo's own warnings and errors (every layer may import this module).

The test suite turns :class:`JaxgeoWarning` into an error unless a test expects it
(``pytest.warns``), so that no warning of ours passes unnoticed.
"""

from __future__ import annotations


class JaxgeoWarning(UserWarning):
    """A result was produced, but something about it needs the user's attention."""


class JaxgeoError(Exception):
    """Base of jaxgeo's own errors: an input or a computation jaxgeo refuses, with a message
    naming the file, line, image, point or setting at fault. Each subclass also derives from
    the builtin it refines (``ValueError`` for bad input), so ``except ValueError`` still
    catches it."""
