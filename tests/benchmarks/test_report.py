"""benchmarks/README.md and README.md's results table are what ``python -m benchmarks.report``
makes of the JSON in ``benchmarks/results/``; every result is named by the convention, belongs
to a study and records its machine, date and command; the timing harness times what it says.

(Not named test_readme.py: the test directories are not packages, basenames must be unique.)"""

import json

import pytest

from benchmarks import harness, report
from benchmarks.data import REPO, RESULTS


def test_benchmarks_readme_is_generated_from_the_results():
    assert (REPO / "benchmarks" / "README.md").read_text() == report.benchmarks_readme(), (
        "benchmarks/README.md is out of date: run python -m benchmarks.report"
    )


def test_readme_table_is_generated_from_the_results():
    readme = (REPO / "README.md").read_text()
    _, found, rest = readme.partition(report.MARKER)
    block, found2, _ = rest.partition(report.MARKER)
    assert found and found2, "README.md lost its results-table markers"
    assert block.strip() == report.table().strip(), (
        "README.md's results table is out of date: run python -m benchmarks.report"
    )
    rows = [line for line in block.strip().splitlines() if line.startswith("| ")]
    assert 6 <= len(rows) - 1 <= 10  # the headline figures only (header row aside)
    assert "(benchmarks/README.md)" in block  # and where the rest is


def test_check_mode_agrees(capsys):
    assert report.main(["--check"]) == 0, capsys.readouterr().out


def test_every_result_is_named_listed_and_reproducible():
    text = (REPO / "benchmarks" / "README.md").read_text()
    paths = sorted(RESULTS.glob("*.json"))
    assert len(paths) >= 15
    for path in paths:
        r = report.load(path)  # name, study and machine entry checked
        assert r.group in ("speed", "accuracy")
        assert f"#### `{path.name}`" in text
        assert r.reproduce() in text
        assert r.reproduce().startswith(f"python -m benchmarks.{r.group}.{r.study}")
        assert len(r.machine["date"]) >= 10 and r.machine["date"][:4].isdigit()
    assert not list(RESULTS.glob("*")) or {p.suffix for p in RESULTS.iterdir()} == {".json"}


@pytest.mark.parametrize(
    "name",
    ["projection.json", "projection-1e6-2core-cpu.txt", "projection-1e6-x-2core-cpu.json",
     "Projection-1e6-2core-cpu.json", "projection-1e6-cpu.json"],
)  # fmt: skip
def test_result_names_outside_the_convention_are_refused(tmp_path, name):
    (tmp_path / name).write_text("{}")
    with pytest.raises(ValueError, match="not named"):
        report.load(tmp_path / name)


def test_a_result_of_no_study_or_without_its_machine_is_refused(tmp_path):
    machine = {"cores": 2, "date": "2026-11-27", "command": "python -m benchmarks.speed.nothing"}
    path = tmp_path / "nothing-1e6-2core-cpu.json"
    path.write_text(json.dumps({"machine": machine}))
    with pytest.raises(ValueError, match="no study 'nothing'"):
        report.load(path)
    path = tmp_path / "batch-10k-2core-cpu.json"
    path.write_text(json.dumps({"jaxgeo_s": 1.0}))
    with pytest.raises(ValueError, match="machine"):
        report.load(path)
    path.write_text(json.dumps({"machine": machine}))  # another study's command
    with pytest.raises(ValueError, match="not of its study"):
        report.load(path)


def test_best_of_warms_up_then_keeps_the_best(monkeypatch):
    calls = []

    def fn():
        calls.append(1)
        return len(calls)

    # the clock read before and after each call: warm-up 9 s, then 5, 3 and 4 s
    times = iter([0.0, 9.0, 10.0, 15.0, 20.0, 23.0, 30.0, 34.0])
    monkeypatch.setattr(harness.time, "perf_counter", lambda: next(times))
    t = harness.best_of(fn, repeats=3)
    assert len(calls) == 4 and t.out == 4  # one warm-up call, then the three timed
    assert t.first_s == 9.0 and t.runs_s == (5.0, 3.0, 4.0) and t.best_s == 3.0


def test_best_of_waits_on_jax_results():
    import jax.numpy as jnp

    t = harness.best_of(lambda: jnp.ones(3) * 2, repeats=2)
    assert t.best_s > 0 and t.best_s <= max(t.runs_s) and len(t.runs_s) == 2
    assert float(t.out.sum()) == 6.0
    assert harness.best_time(lambda: 1.0, 0) == (float("inf"), 1.0)


def test_repeats_for_small_sizes():
    assert harness.repeats_for(10_000_000, 20) == 20
    assert harness.repeats_for(100, 3) == 1000
    assert harness.repeats_for(10_000, 3) == 10


def test_ratio_is_the_peers_time_over_ours():
    assert harness.ratio_vs(0.5, {"gdal": 2.0, "numpy": 0.25}) == {
        "ratio_vs_gdal": 4.0,
        "ratio_vs_numpy": 0.5,
    }


def test_machine_describes_this_run():
    m = harness.machine()
    for key in ("cpu", "arch", "cores", "jax", "jaxlib", "jaxgeo", "date", "command"):
        assert m[key], key
    assert harness.result_name("projection", "1e6", m) == (
        f"projection-1e6-{m['cores_usable']}core-{m.get('backend', 'cpu')}.json"
    )
    assert harness.RESULT_NAME.match(harness.result_name("batch", "10k_l2", m, loaded=True))
    with pytest.raises(ValueError, match="no '-' in case"):
        harness.result_name("batch", "10k-l2", m)


def test_emit_prints_the_result_with_its_machine(capsys):
    out = harness.emit({"jaxgeo_s": 0.5})
    printed = json.loads(capsys.readouterr().out)
    assert printed == out and list(printed) == ["jaxgeo_s", "machine"]
    assert printed["machine"]["date"].startswith("20")
