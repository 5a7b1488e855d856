"""``--report``: the HTML page of a command's result (:mod:`jaxgeo.report`), one option and one
check shared by ``adjust``, ``strip``, ``dsm``, ``coregister`` and ``ortho``.

Where it goes (docs/cli-conventions.md): ``report.html`` in the output folder of ``adjust`` and
``strip`` (``-o DIR``, beside ``report.txt`` and ``report.json``); beside the raster of ``dsm``,
``ortho`` and ``coregister``, named after it (``-o dsm.tif`` -> ``dsm.report.html``). It follows
the outputs' rules: checked and claimed before any computation, never over an input, an
existing page replaced only with ``--overwrite``, written atomically after the product.
"""

from __future__ import annotations

import argparse
import pathlib


def add_report(parser: argparse.ArgumentParser, where: str) -> None:
    """``--report`` (a flag) whose page goes ``where`` (words for the help)."""
    parser.add_argument("--report", action="store_true", help="also write an HTML report with "
                        f"the figures to judge the result ({where}; one self-contained file: "
                        "it opens offline)")  # fmt: skip


def report_target(args: argparse.Namespace, inputs, folder: bool) -> pathlib.Path | None:
    """The page ``--report`` asks for, checked and claimed before any computation: in ``-o``
    (``folder``) or beside it; ``None`` without ``--report``."""
    from ..io.internal import claim_output
    from ..report import report_beside
    from . import CommandError
    from ._common import guard_outputs
    from ._run import CommandRun

    if not getattr(args, "report", False):
        return None
    if not args.out:
        raise CommandError("--report writes report.html into the output folder: give -o DIR")
    path = pathlib.Path(args.out) / "report.html" if folder else report_beside(args.out)
    if path.parent.is_dir():  # (a folder -o makes is checked by the command's own guard)
        guard_outputs([path], inputs, args.overwrite)
    elif path.exists() and not args.overwrite:  # pragma: no cover (a folder is never a file)
        raise CommandError(f"{path}: exists; pass --overwrite to replace it")
    run = CommandRun.current
    if run is not None and not folder:  # (a folder's files are claimed with it)
        run.claims.append(claim_output(path, run.command, overwrite=args.overwrite))
    return path
