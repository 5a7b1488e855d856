"""mkdocs hook: expand ``::: public jaxgeo.NAME`` into the module's docstring and one
mkdocstrings block per public name it re-exports (``from .x import Y as Y``, or the lazy
``_EXPORTS`` table of ``jaxgeo/__init__.py``), so the API pages follow the code."""

from __future__ import annotations

import ast
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
MARKER = re.compile(r"^::: public (jaxgeo(?:\.\w+)*)\s*$", re.MULTILINE)


def _source(module: str) -> pathlib.Path:
    path = ROOT.joinpath(*module.split("."))
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def _is_class(module: str, name: str) -> bool:
    """Whether ``module`` defines ``name`` as a class (e.g. ``RESULTS``, an enumeration)."""
    tree = ast.parse(_source(module).read_text())
    return any(isinstance(n, ast.ClassDef) and n.name == name for n in tree.body)


def public_names(module: str) -> list[tuple[str, str]]:
    """``(qualified name to document, heading name)`` of the names ``module`` re-exports."""
    tree = ast.parse(_source(module).read_text())
    out = []
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            for a in node.names:
                where = f"{module}.{node.module}"
                # constants are documented in their module; upper-case classes (RESULTS) here
                if a.asname == a.name and (not a.name.isupper() or _is_class(where, a.name)):
                    out.append((f"{where}.{a.name}", a.name))
        elif isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "_EXPORTS" for t in node.targets
        ):
            for where, names in ast.literal_eval(node.value).items():
                out += [(f"{where}.{n}", n) for n in names]
    return out


def expand(match: re.Match) -> str:
    module = match.group(1)
    lines = [
        f"::: {module}",
        "    options:",
        "      members: false",
        "      show_root_heading: false",
    ]
    for target, _ in public_names(module):
        lines += ["", f"::: {target}", "    options:", "      heading_level: 2"]
    return "\n".join(lines)


def on_page_markdown(markdown: str, **_) -> str:
    return MARKER.sub(expand, markdown)
