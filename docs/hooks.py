"""mkdocs hook: expand ``::: public jaxgeo.NAME`` into the module's docstring and one
mkdocstrings block per public name it re-exports (``from .x import Y as Y``, or the lazy
``_EXPORTS`` table of ``jaxgeo/__init__.py``), so the API pages follow the code; and
``::: cli-reference`` into the reference of every ``jaxgeo`` command, sub-command and option
(help, default, exit status) walked from the argparse parsers, so it cannot be stale."""

from __future__ import annotations

import ast
import pathlib
import re
import sys

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


# --- the command-line reference (docs/cli.md), generated from the argparse parsers ---

CLI_MARKER = re.compile(r"^::: cli-reference\s*$", re.MULTILINE)
_ESCAPE = str.maketrans({c: f"\\{c}" for c in "\\`*_[]|#"})


def _text(text: str | None) -> str:
    """Help or description text for a Markdown paragraph or table cell: one line, HTML and
    Markdown characters escaped (a help string is plain text; its ````code```` spans kept)."""
    import html

    parts = re.split(r"``(.+?)``", " ".join((text or "").split()))
    return "".join(
        _code(part) if i % 2 else html.escape(part, quote=False).translate(_ESCAPE)
        for i, part in enumerate(parts)
    )


def _code(text: str) -> str:
    """``text`` as an inline code span (HTML-escaped: a table cell holds raw HTML)."""
    import html

    return f"<code>{html.escape(text, quote=False)}</code>"


def cli_parsers() -> list[tuple[str, object]]:
    """``(command line, parser)`` of ``jaxgeo`` and of every command and sub-command, in the
    order of ``jaxgeo --help`` (each command's parser built with its module, as when it runs)."""
    import argparse

    if sys.path[:1] != [str(ROOT)]:  # this tree's commands, not an installed jaxgeo's
        sys.path.insert(0, str(ROOT))
    from jaxgeo.cli import COMMANDS, build_parser

    out = [("jaxgeo", build_parser())]

    def walk(path: str, parser: argparse.ArgumentParser) -> None:
        out.append((path, parser))
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(f"{path} {name}", sub)

    for name in COMMANDS:
        top = build_parser(name)
        sub = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))
        walk(f"jaxgeo {name}", sub.choices[name])
    return out


def _default(action) -> str:
    import argparse

    value = action.default
    if value is None or value is False or value == [] or value == argparse.SUPPRESS:
        return ""
    if action.nargs == 0:  # a flag: its default is not what a user types
        return ""
    if isinstance(value, (list, tuple)):
        value = " ".join(map(str, value))
    return _code(str(value))


def _command_rows(parser, path: str) -> list[str]:
    """One row per sub-command of ``parser``: its name (a link to its section) and help line."""
    import argparse

    rows = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                anchor = f"{path} {choice.dest}".replace(" ", "-")
                rows.append(f"| [{_code(choice.dest)}](#{anchor}) | {_text(choice.help)} |")
    return rows


def _option_rows(parser, actions) -> list[str]:
    import argparse

    formatter = parser._get_formatter()
    rows = []
    for action in actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if action.option_strings:
            metavar = (
                formatter._format_args(action, action.dest.upper()) if action.nargs != 0 else ""
            )
            names = ", ".join(_code(f"{o} {metavar}".strip()) for o in action.option_strings)
        else:
            names = _code(formatter._metavar_formatter(action, action.dest)(1)[0])
        help_ = formatter._expand_help(action) if action.help else ""
        if action.choices is not None and action.metavar is not None:  # (else in the usage)
            help_ += f" (one of: {', '.join(map(str, action.choices))})"
        if action.required and action.option_strings:
            help_ += " (required)"
        rows.append(f"| {names} | {_text(help_)} | {_default(action)} |")
    return rows


def _exit_rows(epilog: str | None) -> list[str]:
    """The ``exit status`` lines of an epilog (``  NNN  text`` and their continuations)."""
    codes: list[list[str]] = []
    inside = False
    for line in (epilog or "").splitlines():
        if line.startswith("exit status:"):
            inside = True
        elif inside and (m := re.match(r"^\s+(\d+)\s+(.*)$", line)):
            codes.append([m.group(1), m.group(2)])
        elif inside and line.startswith("       ") and codes:
            codes[-1][1] += " " + line.strip()
        elif inside:
            inside = False
    return [f"| {code} | {_text(text)} |" for code, text in codes]


def _description(parser) -> list[str]:
    """A description as a paragraph, or as preformatted text where its lines are laid out
    (indented lists of a ``RawDescriptionHelpFormatter``)."""
    text = (parser.description or "").strip("\n")
    if not text:
        return []
    if any(line.startswith(" ") for line in text.splitlines()):
        return ["```text", text, "```", ""]
    return [_text(text), ""]


def cli_reference() -> str:
    """The Markdown of every command: description, usage, its sub-commands, one table of
    arguments per group (help, choices, default), its exit status; built from the parsers at
    docs build time. Headings ``## jaxgeo CMD`` (anchor ``jaxgeo-CMD``), ``### jaxgeo CMD
    SUB``."""
    lines = []
    for path, parser in cli_parsers():
        depth = max(path.count(" "), 1)
        lines += ["", f"{'#' * (depth + 1)} {path}", "", *_description(parser)]
        lines += ["```text", parser.format_usage().strip(), "```", ""]
        commands = _command_rows(parser, path)
        if commands:
            lines += ["**commands**", "", "| command | what |", "|---|---|", *commands, ""]
        for group in parser._action_groups:
            rows = _option_rows(parser, group._group_actions)
            if not rows:
                continue
            lines += [f"**{_text(group.title)}**", "", "| argument | what | default |",
                      "|---|---|---|", *rows, ""]  # fmt: skip
        prose = (parser.epilog or "").partition("exit status:")[0].strip()
        lines += [line for par in prose.split("\n\n") if par for line in (_text(par), "")]
        exits = _exit_rows(parser.epilog)
        if exits:
            lines += ["**exit status**", "", "| code | meaning |", "|---|---|", *exits, ""]
        elif depth == 2:
            lines += ["Exit status: that of the command above.", ""]
    return "\n".join(lines)


def on_page_markdown(markdown: str, **_) -> str:
    markdown = MARKER.sub(expand, markdown)
    if CLI_MARKER.search(markdown):
        markdown = CLI_MARKER.sub(lambda _: cli_reference(), markdown)
    return markdown
