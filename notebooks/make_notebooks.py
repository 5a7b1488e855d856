"""Build and run the notebooks (``notebooks/NN_*.ipynb``) from their percent-format sources
(``notebooks/src/NN_*.py``; cells start with ``# %%``, markdown cells with ``# %% [markdown]``
and every line commented).

Edit the source, then run ``python notebooks/make_notebooks.py``: it builds every notebook from
its source and executes it top to bottom with nbclient in a fresh kernel (full mode, as a reader
runs it: ``JAXGEO_NOTEBOOK_QUICK=0``, no compilation cache, figures inline as PNG), so the
committed notebooks carry their outputs, tables and figures for the documentation site, which
renders them as they are (mkdocs-jupyter, ``execute: false``). It takes minutes per notebook
(printed, and in each notebook's last line). Options:

- ``NN ...`` (e.g. ``02 04``): only those notebooks;
- ``--keep-outputs``: for an edit of the prose only: rebuild from the sources and keep the
  outputs of the notebooks as they are; refused for a notebook whose code cells changed;
- ``--quick``: quick mode (``JAXGEO_NOTEBOOK_QUICK=1``, what the tests run), only with
  ``--out DIR``: the committed notebooks are the full runs.

The tests (``tests/test_notebooks.py``) check that each notebook's code and markdown cells are
its source's, and that it was executed in full with a figure; ``tests/notebooks`` runs each one
in quick mode (:func:`execute`, as here) and checks the numbers its text claims.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import tempfile
import time

import nbformat

HERE = pathlib.Path(__file__).resolve().parent
REPO = HERE.parent
SOURCES = HERE / "src"
KERNELSPEC = {"display_name": "Python 3", "language": "python", "name": "python3"}
RESULTS_PREFIX = "NOTEBOOK_RESULTS "
"""A notebook prints its key numbers as one line: this prefix, then a JSON object."""


def cells(text: str) -> list:
    out, kind, lines = [], None, []

    def flush():
        body = "\n".join(lines).strip("\n")
        if kind == "markdown":
            body = "\n".join(ln[2:] if ln.startswith("# ") else ln.lstrip("#") for ln in
                             body.splitlines())  # fmt: skip
            out.append(nbformat.v4.new_markdown_cell(body))
        elif kind == "code" and body:
            out.append(nbformat.v4.new_code_cell(body))

    for line in text.splitlines():
        if line.startswith("# %%"):
            flush()
            kind, lines = ("markdown" if "[markdown]" in line else "code"), []
        else:
            lines.append(line)
    flush()
    return out


def notebook(source: pathlib.Path) -> nbformat.NotebookNode:
    """The notebook of ``source``, without outputs (deterministic: the same bytes every time)."""
    nb = nbformat.v4.new_notebook()
    nb.cells = cells(source.read_text())
    for i, cell in enumerate(nb.cells):  # stable ids: rebuilding gives the same bytes
        cell["id"] = f"{source.stem[:2]}-{i:02d}"
    nb.metadata = {"kernelspec": dict(KERNELSPEC), "language_info": {"name": "python"}}
    return nb


def render(source: pathlib.Path) -> str:
    """``notebook(source)`` as the text of an ``.ipynb`` file, without outputs."""
    return write(notebook(source))


def write(nb: nbformat.NotebookNode) -> str:
    return nbformat.writes(nb) + "\n"


def cell_sources(nb: nbformat.NotebookNode) -> list[tuple[str, str, str]]:
    """(type, id, source) of every cell: what must agree between a notebook and its source."""
    return [(c.cell_type, c.get("id", ""), c.source) for c in nb.cells]


def execute(
    nb: nbformat.NotebookNode, *, quick: bool, cwd: pathlib.Path, timeout: int | None = None
) -> float:
    """Run ``nb`` top to bottom in place (its outputs replaced) in a fresh kernel of this
    interpreter, with this repository's ``jaxgeo`` first on its path, figures inline (PNG),
    ``JAXGEO_NOTEBOOK_QUICK`` set from ``quick`` and no compilation cache; the kernel works in
    ``cwd`` and inherits the rest of this process' environment. An error in any cell raises
    (nbclient's ``CellExecutionError``); ``timeout`` (s) is per cell. Returns the wall time
    (s)."""
    import nbclient
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import KernelManager

    env = {
        "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p),
        # inline PNG figures, even where the environment names another backend (e.g. Agg)
        "MPLBACKEND": "module://matplotlib_inline.backend_inline",
        "JAXGEO_NOTEBOOK_QUICK": "1" if quick else "0",
        # no persistent compilation cache: the run time a notebook records is a first run's
        "JAXGEO_CACHE_DIR": "off",
    }
    with tempfile.TemporaryDirectory(prefix="jaxgeo-kernels-") as root:
        spec = pathlib.Path(root) / "kernels" / "jaxgeo-notebook"
        spec.mkdir(parents=True)
        argv = [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"]
        (spec / "kernel.json").write_text(
            json.dumps({"argv": argv, "display_name": "jaxgeo", "language": "python", "env": env})
        )
        specs = KernelSpecManager()
        specs.kernel_dirs = [str(spec.parent)]
        km = KernelManager(kernel_name="jaxgeo-notebook", kernel_spec_manager=specs)
        client = nbclient.NotebookClient(
            nb,
            km=km,
            timeout=timeout,
            record_timing=False,  # no time stamps in the cells' metadata
            resources={"metadata": {"path": str(cwd)}},
        )
        t = time.perf_counter()
        try:
            client.execute()
        finally:  # nbclient leaves a kernel it was handed running (each holds 1-3 GB)
            if km.has_kernel:
                km.shutdown_kernel(now=True)
    nb.metadata["kernelspec"] = dict(KERNELSPEC)  # what a reader's Jupyter should start
    return time.perf_counter() - t


def printed(nb: nbformat.NotebookNode) -> str:
    """Everything the code cells printed (stdout and stderr)."""
    return "".join(
        o.get("text", "")
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if o.output_type == "stream"
    )


def results(nb: nbformat.NotebookNode) -> dict:
    """The JSON object an executed notebook printed after ``RESULTS_PREFIX`` (exactly one)."""
    lines = [ln for ln in printed(nb).splitlines() if ln.startswith(RESULTS_PREFIX)]
    if len(lines) != 1:
        raise ValueError(f"{len(lines)} lines start with {RESULTS_PREFIX!r}, not one")
    return json.loads(lines[0][len(RESULTS_PREFIX) :])


def figures(nb: nbformat.NotebookNode) -> int:
    """The number of PNG images among the outputs."""
    return sum(
        "image/png" in o.get("data", {})
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
    )


def keep_outputs(new: nbformat.NotebookNode, old: nbformat.NotebookNode) -> None:
    """Give ``new`` (just built) the outputs of ``old`` (executed), whose code it shares."""
    code = [(c.id, c.source) for c in new.cells if c.cell_type == "code"]
    if code != [(c.get("id"), c.source) for c in old.cells if c.cell_type == "code"]:
        raise ValueError("its code cells changed: run it again (without --keep-outputs)")
    ran = {c.id: c for c in old.cells if c.cell_type == "code"}
    for cell in new.cells:
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = ran[cell.id].outputs, ran[cell.id].execution_count
    new.metadata = old.metadata


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("only", nargs="*", help="notebook numbers (e.g. 02 04); default: all")
    parser.add_argument("--keep-outputs", action="store_true", help="prose edits: do not run")
    parser.add_argument("--quick", action="store_true", help="quick mode (needs --out)")
    parser.add_argument("--out", type=pathlib.Path, default=HERE, help="where to write them")
    parser.add_argument("--timeout", type=int, default=3600, help="per cell (s)")
    args = parser.parse_args(argv)
    if args.quick and args.out.resolve() == HERE:
        parser.error("--quick needs --out DIR: the committed notebooks are full runs")
    sources = sorted(SOURCES.glob("[0-9][0-9]_*.py"))
    if args.only:
        sources = [s for s in sources if s.stem[:2] in args.only]
        if {s.stem[:2] for s in sources} != set(args.only):
            parser.error(f"no such notebook among {args.only}")
    args.out.mkdir(parents=True, exist_ok=True)
    failed = 0
    for source in sources:
        target = args.out / f"{source.stem}.ipynb"
        nb = notebook(source)
        if args.keep_outputs:
            try:
                keep_outputs(nb, nbformat.read(target, as_version=4))
            except (OSError, ValueError) as e:
                print(f"{target.name}: not rebuilt: {e}", file=sys.stderr)
                failed += 1
                continue
            note = "outputs kept"
        else:
            try:
                with tempfile.TemporaryDirectory(prefix="jaxgeo-notebook-") as cwd:
                    wall = execute(
                        nb, quick=args.quick, cwd=pathlib.Path(cwd), timeout=args.timeout
                    )
            except Exception as e:  # a failing cell: the others still run; nothing written
                print(f"{target.name}: not rebuilt: {e}", file=sys.stderr)
                failed += 1
                continue
            note = f"executed ({'quick' if args.quick else 'full'} mode) in {wall:.0f} s"
        target.write_text(write(nb))
        print(f"{target}: {note}, {figures(nb)} figure(s)", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
