"""The run of one command, from its start to its end: the outputs it claimed and, with
``--json``, the one JSON object it prints (``ok``, ``exit_code`` and, when it fails, ``error``,
beside its result; a usage error's: :func:`._common.parse`)."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
from collections.abc import Iterator

from ._common import _BASE_CODES, EXIT_INPUT, _jsonable, note

_FAILED = {
    1: "the computation did not converge",
    3: "the observations do not fit the models",
    4: "the output could not be written",
}
"""``error`` of the JSON object of a command that ends with a result but not with success."""


class CommandRun:
    """What one command run holds from its start to its end: the outputs it claimed and, with
    ``--json``, the one JSON object it prints at the end (:func:`print_json` keeps the result;
    :meth:`finish` prints it with ``ok``, ``exit_code`` and, on failure, ``error``)."""

    current: CommandRun | None = None

    def __init__(self, name: str, argv: list[str], json: bool) -> None:
        self.name, self.json = name, json
        self.command = " ".join(["jaxgeo", *argv])
        self.claims: list = []
        self.result: dict | None = None
        self.error: str | None = None

    def start(self, args: argparse.Namespace) -> None:
        """Before any file is read: a compilation cache that cannot be used said as a warning
        line; the outputs of ``args`` claimed (:data:`OUTPUT_OPTIONS`,
        :func:`jaxgeo.io.internal.claim_output`): a path another live run claimed is refused
        (exit 2) unless ``--overwrite``; the notes as warning lines."""
        from .._runtime.jaxconfig import cache_problem
        from ..io.internal import claim_output

        problem = cache_problem()
        if problem:
            note(f"{self.name}: warning: {problem}")
        names = ["plan" if getattr(args, "plan", None) else "out", *OUTPUT_OPTIONS[1:]]
        paths = [p for p in (getattr(args, n, None) for n in names) if p]
        overwrite = bool(getattr(args, "overwrite", False))
        seen = set()
        for path in paths:
            if os.path.abspath(path) in seen:  # (--keep DIR naming -o's path: claimed once)
                continue
            seen.add(os.path.abspath(path))
            claim = claim_output(path, self.command, overwrite=overwrite)
            self.claims.append(claim)
            if claim.note:
                note(f"{self.name}: warning: {claim.note}")

    def release(self) -> None:
        for claim in reversed(self.claims):
            claim.release()
        self.claims = []

    def say_error(self, line: str) -> None:
        """The error line on stderr, kept for the JSON object."""
        print(line, file=sys.stderr, flush=True)
        self.error = line.removeprefix(f"{self.name}: error: ")

    def report(self, err: Exception, one_line) -> int:
        """Print ``err`` as one line (``one_line``: its text); its exit status (bad input, or a
        bug: re-raised with ``JAXGEO_TRACEBACK=1``)."""
        from ..errors import JaxgeoError
        from ._common import EXIT_INTERNAL

        name = self.name
        if isinstance(err, (JaxgeoError, ValueError, FileNotFoundError, FileExistsError, KeyError)):
            self.say_error(f"{name}: error: {one_line(err)}")
            return EXIT_INPUT
        if isinstance(err, OSError):  # permissions, a full disk, a folder where a file is expected
            where = f"{err.filename}: " if getattr(err, "filename", None) else ""
            self.say_error(f"{name}: error: {where}{err.strerror or one_line(err)}")
            return EXIT_INPUT
        if os.environ.get("JAXGEO_TRACEBACK"):
            raise err
        self.say_error(
            f"{name}: internal error ({type(err).__name__}: {one_line(err)}); this is a bug: "
            "please report it (JAXGEO_TRACEBACK=1 shows the traceback)"
        )
        return EXIT_INTERNAL

    def finish(self, code: int) -> int:
        """With ``--json``: the one JSON object on stdout, the result's (if the command got one)
        with ``ok``, ``exit_code`` and, unless it succeeded, ``error``. The exit status (2 if
        stdout is closed)."""
        if not self.json:
            return code
        reply = {**(self.result or {}), "ok": code == 0, "exit_code": code}
        if code != 0:
            reply["error"] = self.error or _FAILED.get(code, _BASE_CODES.get(code, "failed"))
        try:
            print(json.dumps(reply, default=_jsonable), flush=True)
        except BrokenPipeError:  # (a reader that stopped: `| head`)
            print(f"{self.name}: error: stdout: Broken pipe", file=sys.stderr)
            with contextlib.suppress(OSError):  # no second complaint at the interpreter's exit
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return code or EXIT_INPUT
        return code


OUTPUT_OPTIONS = ("out", "keep", "resume")
"""The options that name what a command writes (``--plan`` instead of ``--out`` when given:
the product is then only named)."""


@contextlib.contextmanager
def command_run(name: str, argv: list[str], args: argparse.Namespace) -> Iterator[CommandRun]:
    """The run of one command (:class:`CommandRun`): its claims released at the end, whatever
    ends it. A jaxgeo warning that no command caught is printed as its line,
    ``jaxgeo COMMAND: warning: ...`` (never Python's ``file:line: TieWarning:`` and source
    line); other libraries' warnings keep Python's display."""
    import warnings

    from ..errors import JaxgeoWarning

    run = CommandRun(name, argv, bool(getattr(args, "json", False)))
    previous, CommandRun.current = CommandRun.current, run
    with warnings.catch_warnings():  # (restores the display at the end)
        show = warnings.showwarning

        def line(message, category, filename, lineno, file=None, text=None):
            if not issubclass(category, JaxgeoWarning):
                return show(message, category, filename, lineno, file, text)
            one = " ".join(str(message).split())
            print(f"{name}: warning: {one}", file=sys.stderr, flush=True)

        if _displayed():  # (a caller recording warnings, pytest.warns, keeps them)
            warnings.showwarning = line
        try:
            yield run
        finally:
            run.release()
            CommandRun.current = previous


def _displayed() -> bool:
    """Whether warnings are displayed (Python's own display in effect), not recorded by a caller
    (``warnings.catch_warnings(record=True)`` replaces the display's implementation)."""
    import warnings

    impl = getattr(warnings, "_showwarnmsg_impl", None)
    return warnings.showwarning is getattr(warnings, "_showwarning_orig", None) and (
        getattr(impl, "__module__", "warnings") == "warnings"
    )
