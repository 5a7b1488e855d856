"""The process's interruption request (Ctrl-C, SIGTERM), shared by the command line and the writers.

The ``jaxgeo`` command's signal handler records the request here and raises ``KeyboardInterrupt``.
Python drops an exception raised where it cannot propagate (a garbage-collector callback, a
``__del__``: "Exception ignored in ..."), so the request is also kept as state: once it is set,
:func:`jaxgeo.io.atomic_output` commits nothing (it raises ``KeyboardInterrupt`` instead of
renaming the temporary file onto the output), and the command ends with exit status 130 even if
the exception was lost. Standard library only: it is imported by the light command-line module.
"""

from __future__ import annotations

import threading

_REQUESTED = threading.Event()


def request() -> None:
    """Record that the process was asked to stop."""
    _REQUESTED.set()


def requested() -> bool:
    """Whether the process was asked to stop (and has not been reset since)."""
    return _REQUESTED.is_set()


def reset() -> None:
    """Forget a request (the start of a command run in-process, after a previous one)."""
    _REQUESTED.clear()


def check() -> None:
    """Raise ``KeyboardInterrupt`` if the process was asked to stop."""
    if _REQUESTED.is_set():
        raise KeyboardInterrupt
