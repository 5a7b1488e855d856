"""The tile runner in this process: results recorded atomically, no-data tiles, retries that
end naming the tile, a second run on the same folder reusing finished tiles, another plan's
folder refused. (Worker processes: tests/tiles/test_ortho_tiles.py.)"""

import dataclasses
import pathlib

import numpy as np
import pytest

from jaxgeo.tiles import PlanError, TileError, TileSettings, plan_tiles, run_tiles
from jaxgeo.tiles.internal import NoData

HERE = TileSettings(workers=0, progress=False)


@dataclasses.dataclass(frozen=True)
class Fill:
    """Writes each tile's window filled with ``row + col``; counts its calls in ``log``; no data
    for the tiles in ``empty``; fails ``fail`` times on tile ``flaky`` (calls counted in
    files, so the count survives a new process)."""

    log: str
    empty: tuple = ()
    flaky: str = ""
    fail: int = 0

    def __call__(self, tile, path):
        log = pathlib.Path(self.log)
        log.mkdir(exist_ok=True)
        calls = len(list(log.glob(f"{tile.id}.*")))
        (log / f"{tile.id}.{calls}").touch()
        if tile.id in self.empty:
            raise NoData("nothing here")
        if tile.id == self.flaky and calls < self.fail:
            raise OSError(f"flaky read, call {calls}")
        np.save(open(path, "wb"), np.full((tile.rows, tile.cols), tile.row + tile.col))
        return {"sum": int(tile.rows * tile.cols * (tile.row + tile.col))}


def _calls(log: pathlib.Path, tile_id: str) -> int:
    return len(list(log.glob(f"{tile_id}.*")))


def test_in_process_run_writes_every_tile(tmp_path):
    plan = plan_tiles("demo", 300, 250, 100)
    work = Fill(str(tmp_path / "log"), empty=("r0002c0002",))
    run = run_tiles(plan, work, tmp_path / "w", HERE, suffix=".npy")
    assert run.workers == 0 and run.scheduler is None and run.empty == 1 and run.reused == 0
    for t in plan.tiles:
        r = run.results[t.id]
        if t.id == "r0002c0002":
            assert r.path is None and r.stats == {"no_data": "nothing here"}
            continue
        assert np.array_equal(np.load(r.path), np.full((t.rows, t.cols), t.row + t.col))
        assert r.stats["sum"] == t.rows * t.cols * (t.row + t.col)
    # nothing temporary is left beside the results
    names = {p.name for p in (tmp_path / "w" / "tiles").iterdir()}
    assert all(not n.startswith(".") for n in names)


def test_second_run_reuses_finished_tiles(tmp_path):
    plan = plan_tiles("demo", 300, 250, 100)
    log = tmp_path / "log"
    # the first run stops at a tile that keeps failing: the tiles before it are kept
    failed = r"tile r0001c0001 \(rows 100..199, cols 100..199\) failed after 2 attempts: OSError"
    with pytest.raises(TileError, match=failed):
        run_tiles(plan, Fill(str(log), flaky="r0001c0001", fail=5), tmp_path / "w",
                  dataclasses.replace(HERE, retries=1), suffix=".npy")  # fmt: skip
    assert _calls(log, "r0001c0001") == 2  # one try and one retry
    finished = {p.stem for p in (tmp_path / "w" / "tiles").glob("*.json")}
    assert finished == {"r0000c0000", "r0000c0001", "r0000c0002", "r0001c0000"}
    run = run_tiles(plan, Fill(str(log), flaky="r0001c0001", fail=3), tmp_path / "w",
                    dataclasses.replace(HERE, retries=1), suffix=".npy")  # fmt: skip
    assert run.reused == 4 and run.empty == 0
    assert all(_calls(log, t) == 1 for t in finished)  # not computed again
    assert _calls(log, "r0001c0001") == 4  # failed twice more, then passed
    for t in plan.tiles:
        assert np.load(run.results[t.id].path)[0, 0] == t.row + t.col


def test_a_folder_of_another_plan_is_refused(tmp_path):
    run_tiles(plan_tiles("demo", 30, 30, 10), Fill(str(tmp_path / "log")), tmp_path / "w",
              HERE, suffix=".npy")  # fmt: skip
    with pytest.raises(PlanError, match="holds the tiles of another demo job"):
        run_tiles(plan_tiles("demo", 30, 30, 15), Fill(str(tmp_path / "log")), tmp_path / "w",
                  HERE, suffix=".npy")  # fmt: skip


def test_small_plans_stay_in_process_by_default():
    from jaxgeo.tiles._runner import IN_PROCESS_MAX_PX, resolve_workers
    from jaxgeo.tiles.internal import cores

    small = plan_tiles("demo", 1000, 1000, 256)
    assert resolve_workers(small, None, None) == 0
    large = plan_tiles("demo", 10_000, 10_000, 1024)
    assert large.width * large.height > IN_PROCESS_MAX_PX
    assert resolve_workers(large, None, None) == (cores() if cores() >= 3 else 0)
    assert resolve_workers(large, 0, None) == 0 and resolve_workers(small, 3, None) == 3
    assert resolve_workers(large, None, "tcp://somewhere:8786") == 0
    with pytest.raises(ValueError, match="workers must be >= 0"):
        resolve_workers(small, -1, None)
