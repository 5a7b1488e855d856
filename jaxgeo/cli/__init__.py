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

from ..errors import JaxgeoError

COMMANDS = {
    "demo": "direct georeferencing vs bias-corrected adjustment on the embedded scene",
    "simulate": "write a simulated Cartosat-1 stereo pair or Carto-2S strip",
    "adjust": "bundle block adjustment of RPC images (bias compensation)",
    "strip": "two-level full-strip adjustment of a Carto-2S-style strip of sub-scenes",
    "ortho": "orthorectify an image with any sensor model over a DEM (COG out)",
    "match": "tie points by SIFT matching guided by the sensor models",
    "dsm": "digital surface model from a stereo pair or triplet",
}
"""Sub-commands (module ``jaxgeo.cli.<name>``) and their one-line help."""


class CommandError(JaxgeoError):
    """An error the user can fix; printed without a traceback, exit status 2."""


def version() -> str:
    """jaxgeo's version, from the installed package's metadata."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as _version

    try:
        return _version("jaxgeo")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown (not installed)"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; only ``command``'s module is imported (the others get a placeholder that
    shows their help line)."""
    parser = argparse.ArgumentParser(
        prog="jaxgeo",
        description="Differentiable orientation of high-resolution satellite images.",
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
    return parser


def _one_line(err: BaseException) -> str:
    msg = err.args[0] if isinstance(err, KeyError) and err.args else err
    return " ".join(str(msg).split("\n"))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    # top-level options take no values: the first word that is not an option is the command
    command = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(command if command in COMMANDS else None)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (CommandError, ValueError, FileNotFoundError, FileExistsError, KeyError) as err:
        print(f"jaxgeo {args.command}: error: {_one_line(err)}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
