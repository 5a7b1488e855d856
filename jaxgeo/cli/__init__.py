"""The ``jaxgeo`` command: one module per sub-command, each with ``register(subparsers)``.

A sub-command module defines ``register(sub)`` that adds its parser and sets ``func`` to a
function ``run(args) -> int``. Heavy imports happen inside ``run`` so ``jaxgeo --help`` is fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys

COMMANDS = ("demo", "simulate", "adjust", "strip", "ortho")


class CommandError(Exception):
    """An error the user can fix; printed without a traceback, exit status 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxgeo",
        description="Differentiable orientation of high-resolution satellite images.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"jaxgeo.cli.{name}")
        except ModuleNotFoundError as err:
            if err.name == f"jaxgeo.cli.{name}":
                continue  # sub-command not part of this build
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (CommandError, ValueError, FileNotFoundError, FileExistsError, KeyError) as err:
        msg = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"jaxgeo {args.command}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
