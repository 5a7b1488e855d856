"""Build the notebooks (``notebooks/NN_*.ipynb``, without outputs) from their percent-format
sources (``notebooks/src/NN_*.py``; cells start with ``# %%``, markdown cells with
``# %% [markdown]`` and every line commented). Edit the source, then run
``python notebooks/make_notebooks.py``; the tests check that both agree.
"""

from __future__ import annotations

import pathlib
import sys

import nbformat

HERE = pathlib.Path(__file__).resolve().parent
SOURCES = HERE / "src"


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
    nb = nbformat.v4.new_notebook()
    nb.cells = cells(source.read_text())
    for i, cell in enumerate(nb.cells):  # stable ids: rebuilding gives the same bytes
        cell["id"] = f"{source.stem[:2]}-{i:02d}"
    nb.metadata = {
        "kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
        "language_info": {"name": "python"},
    }
    return nb


def render(source: pathlib.Path) -> str:
    return nbformat.writes(notebook(source)) + "\n"


def main() -> int:
    for source in sorted(SOURCES.glob("[0-9][0-9]_*.py")):
        target = HERE / f"{source.stem}.ipynb"
        target.write_text(render(source))
        print(target.relative_to(HERE.parent))
    return 0


if __name__ == "__main__":
    sys.exit(main())
