"""Set-up of each worker process of the embedded cluster (a dask preload: ``dask_setup``).

Ctrl-C in a terminal interrupts the whole foreground process group. The command handles it (it
closes the cluster, removes its temporary files and exits 130 with one line); a worker that got
it too would print a ``KeyboardInterrupt`` traceback of its own. So each worker ignores SIGINT
and leaves the terminal's process group; it ends when the cluster closes, or when its nanny or
scheduler goes away.
"""

from __future__ import annotations

import contextlib
import os
import signal


def dask_setup(worker) -> None:
    with contextlib.suppress(ValueError):  # not the main thread: nothing to change
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    with contextlib.suppress(OSError, AttributeError):  # (not on Windows)
        os.setpgrp()
