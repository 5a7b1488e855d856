"""README's results table is the one ``benchmarks/readme_table.py`` builds from the JSON in
``benchmarks/results/`` (the machine/date column aside: a checkout's file dates vary)."""

import importlib.util
import pathlib

REPO = pathlib.Path(__file__).resolve().parents[2]


def _rows(text: str) -> list[str]:
    return [line.rsplit("|", 2)[0] for line in text.strip().splitlines()]


def test_readme_table_matches_the_results():
    spec = importlib.util.spec_from_file_location(
        "readme_table", REPO / "benchmarks" / "readme_table.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    readme = (REPO / "README.md").read_text()
    _, _, rest = readme.partition(module.MARKER)
    block, found, _ = rest.partition(module.MARKER)
    assert found, "README.md lost its results-table markers"
    assert _rows(block) == _rows(module.table())
    assert len(_rows(block)) > 10
