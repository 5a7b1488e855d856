"""``adjust_strip_files``: what ``jaxgeo strip`` runs, as one library call on the strip's files."""

import pathlib

import pytest

import jaxgeo.strip._files as files
from jaxgeo.simulate import carto2s_strip
from jaxgeo.strip import (
    ConfigError,
    RefitConfig,
    StripFileAdjustment,
    StripOutputs,
    UniversalCorrectionWarning,
    adjust_strip_files,
    read_strip,
)

FAST = RefitConfig(grid=(9, 9, 5))


@pytest.fixture(scope="module")
def strip_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("strip6")
    carto2s_strip(6, seed=2).save(d)
    return d


def test_files_in_outputs_checked_result_written(strip_dir, tmp_path):
    out = tmp_path / "out"
    with pytest.warns(UniversalCorrectionWarning):  # 3 GCP scenes: a warning, as Python's
        run = adjust_strip_files(strip_dir, outputs=StripOutputs(out, "rpb", refit=FAST))
    assert isinstance(run, StripFileAdjustment)
    assert run.converged and run.poor_fit == ""  # the verdicts are fields, not warnings
    assert strip_dir / "strip.json" in run.inputs and not out.exists()  # checked, not made
    assert "whole strip, level2" in run.format() and run.summary()["report"]["strip"]["converged"]
    data = run.write()  # where the outputs were checked
    names = sorted(pathlib.Path(p).name for p in data["written"])
    assert names == sorted([f"scene_{k:03d}.RPB" for k in range(6)] + ["report.json", "report.txt"])
    assert max(m["rpc_refit_px"]["check_max"] for m in data["models"].values()) < 0.05
    # again: existing outputs are refused (overwrite replaces them), another folder is written
    with pytest.raises(ConfigError):
        run.write(out, rpc_format="rpb", refit=FAST)
    assert len(run.write(out, overwrite=True, rpc_format="rpb", refit=FAST)["written"]) == 8
    assert len(run.write(tmp_path / "other", refit=FAST)["written"]) == 8


def test_outputs_refused_before_any_work(strip_dir, tmp_path, monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("adjusted before the outputs were checked")

    monkeypatch.setattr(files, "adjust_strip", never)
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "report.json").write_text("keep me")
    with pytest.raises(ConfigError, match="refusing to overwrite"):
        adjust_strip_files(strip_dir, outputs=StripOutputs(taken))
    with pytest.raises(ConfigError, match="refusing to overwrite"):  # a Strip already read
        adjust_strip_files(read_strip(strip_dir), outputs=StripOutputs(taken, "txt"))
    assert (taken / "report.json").read_text() == "keep me"
