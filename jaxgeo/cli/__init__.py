"""The ``jaxgeo`` command: parse -> one library call -> print; one module per sub-command.

A sub-command module defines ``register(sub)`` that adds its parser and sets ``func`` to a
function ``run(args) -> int``. The modules are imported only when their sub-command runs, so
``jaxgeo --help`` and ``jaxgeo --version`` never import jax. Library errors (``ValueError``,
missing or existing files) are printed as one line, exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .._runtime import interrupt as _interrupt
from ..errors import JaxgeoError

COMMANDS = {
    "demo": "direct georeferencing vs bias-corrected adjustment on the embedded scene",
    "simulate": "write a simulated scene: cartosat1 (a Cartosat-1 pair), carto2s-strip (a "
    "Carto-2S strip) or stereo-scene (rendered Pleiades-like images with truth)",
    "adjust": "bundle block adjustment of RPC images (bias compensation)",
    "strip": "two-level full-strip adjustment of a Carto-2S-style strip of sub-scenes",
    "ortho": "orthorectify an image with any sensor model over a DEM (COG out)",
    "match": "tie points by SIFT matching guided by the sensor models",
    "dsm": "digital surface model from a stereo pair or triplet",
    "coregister": "align a DSM onto a reference DEM (Nuth and Kääb), statistics before/after",
}
"""Sub-commands (module ``jaxgeo.cli.<name>``) and their one-line help (``jaxgeo --help``; a
command with sub-commands of its own, ``simulate``, names them)."""


class CommandError(JaxgeoError):
    """An error the user can fix; printed without a traceback, exit status 2."""


def version() -> str:
    """jaxgeo's version, from the installed package's metadata (``jaxgeo.__version__``)."""
    from .. import __version__

    return __version__


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; only ``command``'s module is imported (the others get a placeholder that
    shows their help line)."""
    from ._common import SEE_CONVENTIONS, Parser

    parser = Parser(
        prog="jaxgeo",
        description="Differentiable orientation of high-resolution satellite images.",
        epilog="'jaxgeo COMMAND --help' describes a command, its options and its exit status.\n"
        + SEE_CONVENTIONS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, line in COMMANDS.items():
        if name != command:
            sub.add_parser(name, help=line)
            continue
        try:
            module = importlib.import_module(f"jaxgeo.cli._{name}")
        except ModuleNotFoundError as err:
            if err.name == f"jaxgeo.cli._{name}":
                continue  # sub-command not part of this build
            raise
        module.register(sub)
        command_parser = sub.choices.get(name)
        if command_parser is not None and not command_parser.epilog:
            # every command documents its exit status: the shared codes by default
            from ._common import exit_codes

            command_parser.epilog = exit_codes()
            command_parser.formatter_class = argparse.RawDescriptionHelpFormatter
    return parser


def _one_line(err: BaseException) -> str:
    from ._common import OPTION_WORDS

    msg = err.args[0] if isinstance(err, KeyError) and err.args else err
    text = " ".join(str(msg).split("\n"))
    for words, option in OPTION_WORDS.items():
        text = text.replace(words, option)
    return text


def _interrupt_handler(signum, frame):  # pragma: no cover - exercised through a subprocess
    """SIGINT and SIGTERM: record the request, then unwind like Ctrl-C (temporary outputs are
    removed by :func:`jaxgeo.io.atomic_output`)."""
    _interrupt.request()
    raise KeyboardInterrupt


def _redeliver_lost_interrupt(unraisable, previous=sys.unraisablehook):  # pragma: no cover
    """``sys.unraisablehook``: an interruption raised inside a garbage-collector callback or a
    ``__del__`` is dropped by Python; deliver it again to the main thread, where it unwinds the
    command (instead of printing "Exception ignored" and running on). From another thread, a
    moment later: delivered now, it would be raised inside this hook and dropped again."""
    import _thread
    import signal
    import threading

    if isinstance(unraisable.exc_value, KeyboardInterrupt) and _interrupt.requested():
        threading.Timer(0.05, _thread.interrupt_main, args=(signal.SIGINT,)).start()
        return
    previous(unraisable)


def _install_interrupt_handlers() -> dict:
    """Our handlers for SIGINT and SIGTERM (main thread only); the previous ones, to restore."""
    import signal

    _interrupt.reset()
    if not threading_main():
        return {}
    previous = {s: signal.signal(s, _interrupt_handler) for s in (signal.SIGINT, signal.SIGTERM)}
    previous["unraisablehook"] = sys.unraisablehook
    sys.unraisablehook = _redeliver_lost_interrupt
    return previous


def _restore_handlers(previous: dict) -> None:
    import signal

    hook = previous.pop("unraisablehook", None)
    if hook is not None:
        sys.unraisablehook = hook
    for signum, handler in previous.items():
        signal.signal(signum, handler)


def _ignore_signals() -> None:
    import signal

    if threading_main():
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, lambda signum, frame: None)


def main(argv: list[str] | None = None) -> int:
    """Run one sub-command; every error ends as one line on stderr and an exit status (the
    codes of ``jaxgeo.cli._common``), never as a traceback (``JAXGEO_TRACEBACK=1`` re-raises).
    Ctrl-C and SIGTERM end it with status 130 and no output (:mod:`jaxgeo._runtime.interrupt`)."""
    return _main(argv, restore_handlers=True)


def _main(argv: list[str] | None, restore_handlers: bool) -> int:
    from ._common import parse

    argv = sys.argv[1:] if argv is None else list(argv)
    # top-level options take no values: the first word that is not an option is the command
    command = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(command if command in COMMANDS else None)
    args = parse(parser, argv)
    from ._run import command_run

    with command_run(f"jaxgeo {args.command}", argv, args) as run:
        code = _run_command(args, run, restore_handlers)
    return run.finish(code)  # (--json: the one JSON object, once every claim is released)


def _run_command(args: argparse.Namespace, run, restore_handlers: bool) -> int:
    """The command of ``args``, its outputs claimed first; its exit status."""
    # jax: every command computes (help and usage errors are above)
    from .._runtime import exported as _exported
    from .._runtime import progress as _progress
    from ._common import EXIT_INTERRUPTED

    owned = _exported.own_process()  # restored below (tests run commands in their process)
    name = run.name
    interrupted = f"{name}: interrupted; no output was written"
    previous = _install_interrupt_handlers()
    try:
        run.start(args)  # outputs claimed before any file is read
        code = int(args.func(args) or 0)
        if _interrupt.requested():  # its exception was lost after the last output was written
            run.say_error(f"{name}: interrupted after its outputs were written")
            return EXIT_INTERRUPTED
        return code
    except KeyboardInterrupt:
        run.say_error(interrupted)
        return EXIT_INTERRUPTED
    except Exception as err:
        if _interrupt.requested():  # a library turned the interruption into its own error
            run.say_error(interrupted)
            return EXIT_INTERRUPTED
        return run.report(err, _one_line)
    finally:
        _exported.own_process(owned)
        _progress.silence(False)  # --quiet was this run's: later calls in this process decide
        if restore_handlers:
            _restore_handlers(previous)
        elif _interrupt.requested():  # the process is ending: a late signal changes nothing
            _ignore_signals()


GC_THRESHOLD = (10_000, 10, 10)
"""Python's cyclic garbage collector in the command's process (``gc.set_threshold``; Python's
default is ``(700, 10, 10)``): jax's tracing makes many short-lived containers, and with the
default a cold ``jaxgeo demo`` ran some 600 collections, 4 of them over every object of jax,
equinox and jaxgeo, for 0.33-0.51 s; with this 64 collections, none of them full, 0.15 s.
The process's own library calls (tests, notebooks) keep Python's default."""


def entry() -> None:
    """The ``jaxgeo`` command (and ``python -m jaxgeo.cli``): :func:`main`, then exit with its
    status. Before exiting, every object is frozen (``gc.freeze``): the interpreter's teardown
    then skips its last collection over them (0.5 -> 0.2 s after a demo). After an
    interruption the process ends without the interpreter's teardown: XLA's threads may still
    run the computation the interruption abandoned, and tearing the runtime down under them
    can crash the process (exit -11 instead of 130). The outputs were already removed by then
    (:func:`jaxgeo.io.atomic_output`), and the message printed."""
    import gc
    import os

    from ._common import EXIT_INTERRUPTED

    gc.set_threshold(*GC_THRESHOLD)
    code = _main(None, restore_handlers=False)
    if code == EXIT_INTERRUPTED:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    gc.freeze()
    sys.exit(code)


def threading_main() -> bool:
    """Whether this is the main thread (signal handlers can only be set there)."""
    import threading

    return threading.current_thread() is threading.main_thread()


if __name__ == "__main__":  # pragma: no cover
    entry()
