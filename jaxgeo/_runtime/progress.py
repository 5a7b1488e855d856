"""Progress of the long steps a user waits on, with its rate and ETA, on stderr only.

One facility for every command and library stage (tiles, stereo pairs and their bands, matching
pairs, an adjustment's solves): :class:`Progress` over a count of steps. Where it goes:

- a terminal (stderr is a TTY, or a notebook): a tqdm bar with the count, percent, rate and
  ``elapsed<ETA``, the current stage as its postfix;
- anything else (a log file, a pipe, a CI job): sparse plain lines, never carriage returns --
  one when it starts, then one each time another ~10 % is done or, while steps finish, at least
  every ~30 s, and the last (``desc: 3/10 tile (30 %), 0.5 tile/s, elapsed 0:06, ETA 0:14``);
- nothing when it is not ``enabled`` (the library's default: every function that shows progress
  takes ``progress=False`` or a callback, as it did) or while the process is :func:`silenced`
  (the ``jaxgeo`` command's ``--quiet``: no progress whatever a library default says).

It never writes on stdout: a command's ``--json`` object stays the only thing there. Standard
library and tqdm only (the bottom layer: no other jaxgeo package).
"""

from __future__ import annotations

import io
import sys
import time
from collections.abc import Callable
from typing import TextIO

EVERY_FRACTION = 0.1
"""A plain line each time this fraction of the total is done (a log of a long run stays short)."""
EVERY_S = 30.0
"""... and at least one this often (s) while steps finish (a slow run still shows it moves)."""

_SILENT = False


def silence(flag: bool) -> None:
    """Silence every progress display of this process (``True``: the command line's
    ``--quiet``) or let each one's ``enabled`` decide again (``False``)."""
    global _SILENT
    _SILENT = bool(flag)


def silenced() -> bool:
    """Whether progress is silenced for the whole process (:func:`silence`)."""
    return _SILENT


def _on_terminal(file: io.TextIOBase | TextIO) -> bool:
    """A bar (carriage returns) only where a person watches it: a TTY, or a notebook's cell
    (tqdm.auto's widget there; a kernel's stderr is no TTY)."""
    try:
        if file.isatty():
            return True
    except (AttributeError, ValueError):  # a closed or minimal stream
        return False
    return "ipykernel" in sys.modules and file is sys.stderr


def format_s(seconds: float) -> str:
    """``seconds`` as ``m:ss`` or ``h:mm:ss`` (the clock tqdm prints)."""
    s = max(0, int(round(seconds)))
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class Progress:
    """A count of steps done out of ``total`` (``None``: unknown; no percent, no ETA), shown on
    stderr as a bar or as plain lines (module docstring), with its rate in ``unit`` per second
    and the remaining time at that rate. The rate is that of the steps done in this run
    (``initial``, steps done before it -- tiles a resumed run reuses -- count in the total but
    not in the rate), and once two are done, that of the steps after the first: the first
    carries the start-up (a program's compilation, workers starting; measured: the first 2 of
    16 DSM tiles took 9 s each, the others 5 s). ``enabled=False``: silent, every method a
    no-op. A context manager (closed on exit).

    ``note(text)``: the current stage (a bar's postfix; the next plain line's tail).
    ``update(n)``: ``n`` more steps done; ``set(done, total)``: the count (and total) as
    measured elsewhere (a stage reporting ``done of total``); ``say(line)``: a line of its own
    (above a bar).
    """

    def __init__(self, desc: str, total: int | None = None, unit: str = "step", *,
                 enabled: bool = True, initial: int = 0,
                 file: io.TextIOBase | TextIO | None = None) -> None:  # fmt: skip
        self.desc, self.total, self.unit = desc, total, unit
        self.n = self.initial = int(initial)
        self.enabled = bool(enabled) and not _SILENT
        self.file = sys.stderr if file is None else file
        self._note = ""
        self._bar = None
        self._started = self._t0 = self._last_t = time.monotonic()  # (_t0: the rate's clock)
        self._last_n = None  # the count of the last plain line
        self._first = None  # (count, time) when the first step of this run was done
        if not self.enabled:
            return
        if _on_terminal(self.file):
            from tqdm.auto import tqdm

            self._bar = tqdm(total=total, initial=initial, desc=desc, unit=unit,
                             file=self.file, dynamic_ncols=True, leave=True)  # fmt: skip
        else:
            self._line()

    # --- counting -------------------------------------------------------------------------
    def update(self, n: int = 1) -> None:
        """``n`` more steps done."""
        if self._bar is not None:  # tqdm's own pace of redrawing and its smoothed rate
            self.n += n
            self._bar.update(n)
        elif self.enabled:
            self.set(self.n + n)

    def set(self, done: int, total: int | None = None) -> None:
        """``done`` steps of ``total`` (the total unchanged when ``None``)."""
        if not self.enabled:
            return
        if total is not None:
            self.total = int(total)
        self.n = int(done)
        if self._first is None and self.n > self.initial:
            self._first = (self.n, time.monotonic())
        if self._bar is not None:
            if total is not None:
                self._bar.total = self.total
            self._bar.n = self.n
            self._bar.refresh()
        elif self._due():
            self._line()

    def note(self, text: str) -> None:
        """The current stage: the bar's postfix (60 characters), the next plain line's tail.
        While the total is not known, a note restarts the rate's clock: the stages before the
        counted one prepared it (a pair's tie points and rectification before its bands)."""
        if not self.enabled:
            return
        if self.total is None and self.n == self.initial:
            self._t0, self._first = time.monotonic(), None
            if self._bar is not None and self.n == 0:
                self._bar.reset()  # (its clock too)
        self._note = " ".join(str(text).split())
        if self._bar is not None:
            self._bar.set_postfix_str(self._note[:60])

    def say(self, line: str) -> None:
        """``line`` on a line of its own (above the bar on a terminal)."""
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.write(line, file=self.file)
        else:
            print(line, file=self.file, flush=True)

    def close(self) -> None:
        """End the display: a bar stays as it is; the last plain line unless already shown."""
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        elif self._last_n != self.n:
            self._line()
        self.enabled = False  # closed: later calls change nothing

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- the plain lines ------------------------------------------------------------------
    def _due(self) -> bool:
        if self._last_n is None or self.n == self._last_n:
            return False
        if self.total and self.n >= self.total:
            return True
        if time.monotonic() - self._last_t >= EVERY_S:
            return True
        return bool(self.total) and (self.n - self._last_n) >= EVERY_FRACTION * self.total

    def text(self) -> str:
        """The plain line of the count now: count, percent, rate, elapsed time and ETA."""
        now = time.monotonic()
        elapsed, counted = now - self._started, now - self._t0
        of = f"/{self.total}" if self.total is not None else ""
        parts = [f"{self.desc}: {self.n}{of} {self.unit}"]
        if self.total:
            parts[0] += f" ({100.0 * self.n / self.total:.0f} %)"
        done = self.n - self.initial
        rate = done / counted if done > 0 and counted > 0 else None
        if self._first is not None and self.n > self._first[0] and now > self._first[1]:
            rate = (self.n - self._first[0]) / (now - self._first[1])  # after the start-up
        if rate is not None:
            parts.append(f"{rate:.3g} {self.unit}/s" if rate >= 1 else
                         f"{1 / rate:.3g} s/{self.unit}")  # fmt: skip
        parts.append(f"elapsed {format_s(elapsed)}")
        if self.total is not None and rate is not None:
            left = max(self.total - self.n, 0)
            parts.append(f"ETA {format_s(left / rate)}" if left else "done")
        line = ", ".join(parts)
        return f"{line} -- {self._note}" if self._note else line

    def _line(self) -> None:
        print(self.text(), file=self.file, flush=True)
        self._last_n, self._last_t = self.n, time.monotonic()


class Stages:
    """Timed stage lines of a computation whose steps cannot be counted in advance: an
    adjustment (a solve inside one compiled program, then as many snooping rounds, each a
    re-solve, as gross errors are found). Each line given is passed to ``say`` with the time
    since the first stage and the time the previous one took -- the forecast of the next,
    where the same compiled program runs again (the first includes its compilation);
    :meth:`done` the closing line. ``say=None``: silent (the library's default). ``started``:
    the clock runs from now (the first line has its times too), else from the first line."""

    def __init__(self, say: Callable[[str], None] | None, started: bool = False) -> None:
        self.say = say
        self._t0 = self._last = time.monotonic() if started else None

    def __call__(self, line: str) -> None:
        if self.say is None:
            return
        now = time.monotonic()
        if self._t0 is None:
            self._t0 = now
            self.say(line)
        else:
            self.say(f"{line} [{format_s(now - self._t0)} so far, the last step "
                     f"{format_s(now - self._last)}]")  # fmt: skip
        self._last = now

    def done(self, what: str) -> None:
        """``what`` with the time since the first stage (nothing if no stage was told)."""
        if self.say is not None and self._t0 is not None:
            self.say(f"{what} in {format_s(time.monotonic() - self._t0)}")


def say(line: str, enabled: bool = True, file: io.TextIOBase | TextIO | None = None) -> None:
    """``line`` on stderr (or ``file``) when ``enabled`` and progress is not :func:`silenced`:
    a stage without a count (``"[dsm] rasterising"``)."""
    if enabled and not _SILENT:
        print(line, file=sys.stderr if file is None else file, flush=True)
