"""A tiled orthoimage on a dask LocalCluster of 2 spawned workers equals the one made in this
process; a worker killed mid-run still gives the complete, identical product; ``resume`` skips
the tiles an interrupted run finished; a failing tile on a cluster named by its address is
retried, then named; ``jaxgeo ortho --plan`` lists the tiles and computes
nothing. The Ventoux Pleiades crop (500 x 500 px, a pixel-space geotransform at 5000, 5000) on
SRTM + EGM96, in 256 px tiles (9 tiles)."""

import dataclasses
import json
import os
import pathlib
import signal
import time

import numpy as np
import pytest
import rasterio

from jaxgeo.cli import main
from jaxgeo.io import read_dem
from jaxgeo.ortho import OrthoSettings, plan_ortho
from jaxgeo.tiles import TileError, TileSettings, run_tiles
from jaxgeo.tiles._mosaic import mosaic_cog
from jaxgeo.tiles.internal import WorkerPool
from tests.ortho.conftest import ventoux_dem_ellipsoidal  # noqa: F401  (fixture)

HERE = TileSettings(workers=0, progress=False)
QUIET = TileSettings(progress=False)
TILE = 256


@pytest.fixture(scope="module")
def pool():
    """Two spawned worker processes, started first (they import jaxgeo while the plan is made)."""
    with WorkerPool(2, retries=2, warm=("jaxgeo.ortho",)) as p:
        yield p


@pytest.fixture(scope="module")
def crop(real_data):
    return real_data / "ventoux" / "left_image.tif", real_data / "phr_ventoux__left_image.geom"


@pytest.fixture(scope="module")
def setup(pool, crop, ventoux_dem_ellipsoidal, tmp_path_factory):  # noqa: F811
    image, model = crop
    dem = read_dem(ventoux_dem_ellipsoidal, height="ellipsoidal")
    out = tmp_path_factory.mktemp("ortho") / "ortho.tif"
    return plan_ortho(image, dem, out, OrthoSettings(tile_px=TILE), model=model)


def _product(setup, run, out) -> np.ndarray:
    mosaic_cog(run, setup.plan, setup.job.spec, out)
    with rasterio.open(out) as ds:
        return ds.read()


@dataclasses.dataclass(frozen=True)
class Spy:
    """The ortho job, recording which process ran each tile."""

    job: object

    def __call__(self, tile, path):
        stats = self.job(tile, path)
        return None if stats is None else {**stats, "pid": os.getpid()}


@dataclasses.dataclass(frozen=True)
class KillOnce:
    """The ortho job, whose worker process dies (SIGKILL) the first time it starts ``tile_id``."""

    job: object
    tile_id: str
    flag: str

    def __call__(self, tile, path):
        if tile.id == self.tile_id and not os.path.exists(self.flag):
            pathlib.Path(self.flag).write_text(str(os.getpid()))
            os.kill(os.getpid(), signal.SIGKILL)
        return self.job(tile, path)


@dataclasses.dataclass(frozen=True)
class FailOn:
    """The ortho job, failing on ``tile_id`` (an interrupted run)."""

    job: object
    tile_id: str

    def __call__(self, tile, path):
        if tile.id == self.tile_id:
            raise OSError("interrupted")
        return self.job(tile, path)


@dataclasses.dataclass(frozen=True)
class FailOnce:
    """The ortho job, failing the first time it runs ``tile_id`` (a flag file records it)."""

    job: object
    tile_id: str
    flag: str

    def __call__(self, tile, path):
        if tile.id == self.tile_id and not os.path.exists(self.flag):
            pathlib.Path(self.flag).write_text(str(os.getpid()))
            raise OSError("a flaky read")
        return self.job(tile, path)


@pytest.fixture(scope="module")
def in_process(setup, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("in_process")
    run = run_tiles(setup.plan, setup.job, tmp / "work", HERE)
    assert run.workers == 0 and run.scheduler is None
    return _product(setup, run, tmp / "ortho.tif")


def test_two_spawned_workers_give_the_in_process_product(setup, pool, in_process, tmp_path):
    assert len(setup.plan) == 9 and in_process.shape[1:] == (setup.plan.height, setup.plan.width)
    assert 0.8 < np.mean(in_process > 0) < 1.0  # the crop's footprint, nodata around it
    run = run_tiles(setup.plan, Spy(setup.job), tmp_path / "work", QUIET, pool=pool)
    assert run.workers == 2 and run.scheduler.startswith("tcp://")
    pids = {r.stats["pid"] for r in run.results.values() if r.path is not None}
    assert len(pids) == 2 and os.getpid() not in pids  # both workers, none of it here
    methods = pool.client().run(lambda: __import__("multiprocessing").get_start_method())
    assert set(methods.values()) == {"spawn"}
    assert np.array_equal(_product(setup, run, tmp_path / "ortho.tif"), in_process)


@dataclasses.dataclass(frozen=True)
class Stamp:
    """The ortho job, recording when each tile started (the clock every process shares)."""

    job: object

    def __call__(self, tile, path):
        started = time.time()
        stats = self.job(tile, path)
        time.sleep(0.2)  # a tile long enough for both workers to be busy
        return {**(stats or {}), "started": started}


def test_the_costliest_tiles_start_first(setup, pool, tmp_path):
    """Tiles run in the order of their ``cost`` (here the reverse of the plan's), so that the
    run ends on cheap tiles: the two first started are the two costliest, the last the cheapest
    or next to it."""
    n = len(setup.plan.tiles)
    tiles = tuple(dataclasses.replace(t, inputs={**t.inputs, "cost": k})
                  for k, t in enumerate(setup.plan.tiles))  # fmt: skip
    plan = dataclasses.replace(setup.plan, tiles=tiles)
    run = run_tiles(plan, Stamp(setup.job), tmp_path / "work", QUIET, pool=pool)
    started = sorted(run.results, key=lambda k: run.results[k].stats["started"])
    costs = [plan.tiles[[t.id for t in plan.tiles].index(k)].cost for k in started]
    assert sorted(costs[:2]) == [n - 2, n - 1] and costs[-1] <= 1, costs


def test_a_worker_killed_mid_run_leaves_a_complete_identical_product(setup, pool, in_process,
                                                                     tmp_path):  # fmt: skip
    flag = tmp_path / "killed"
    work = KillOnce(setup.job, "r0001c0001", str(flag))
    run = run_tiles(setup.plan, work, tmp_path / "work", QUIET, pool=pool)
    assert flag.exists()  # a worker did die, running that tile
    assert run.results["r0001c0001"].path is not None
    assert np.array_equal(_product(setup, run, tmp_path / "ortho.tif"), in_process)


def test_resume_skips_the_tiles_an_interrupted_run_finished(setup, crop, in_process, tmp_path,
                                                            ventoux_dem_ellipsoidal):  # noqa: F811 # fmt: skip
    work = tmp_path / "work"
    with pytest.raises(TileError, match=r"tile r0001c0002 \(rows 256..511, cols 512..\d+\)"):
        run_tiles(setup.plan, FailOn(setup.job, "r0001c0002"), work,
                  TileSettings(workers=0, retries=0, progress=False))  # fmt: skip
    finished = len(list((work / "tiles").glob("*.json")))
    assert finished == 5  # the tiles before it, in plan order
    image, model = crop
    out = tmp_path / "ortho.tif"
    args = ["ortho", str(image), "--model", str(model), "--dem", str(ventoux_dem_ellipsoidal),
            "--tile", str(TILE), "-o", str(out), "--resume", str(work), "--workers", "0",
            "--quiet", "--json"]  # fmt: skip
    assert main(args) == 0
    assert not work.exists()  # removed once the product is complete
    with rasterio.open(out) as ds:
        assert np.array_equal(ds.read(), in_process)


def test_plan_lists_the_tiles_and_computes_nothing(setup, crop, tmp_path, capsys,
                                                   ventoux_dem_ellipsoidal):  # noqa: F811 # fmt: skip
    image, model = crop
    out, plan_file = tmp_path / "ortho.tif", tmp_path / "plan.json"
    args = ["ortho", str(image), "--model", str(model), "--dem", str(ventoux_dem_ellipsoidal),
            "--tile", str(TILE), "-o", str(out), "--plan", str(plan_file)]  # fmt: skip
    assert main(args) == 0
    assert "9 tiles" in capsys.readouterr().out
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["plan.json"]
    plan = json.loads(plan_file.read_text())
    assert plan["kind"] == "ortho" and plan["n_tiles"] == 9 == len(plan["tiles"])
    assert plan["job"]["image"]["path"] == str(image) and plan["job"]["image_origin"] == [
        5000,
        5000,
    ]
    windows = [t["inputs"]["image_window"] for t in plan["tiles"]]
    assert all(w is not None for w in windows)
    assert all(0 <= w[0] and w[0] + w[2] <= 500 and 0 <= w[1] and w[1] + w[3] <= 500
               for w in windows if w is not None)  # fmt: skip
    # the same plan as the library's (the one --resume checks a folder against)
    assert plan["tiles"] == json.loads(setup.plan.to_json())["tiles"]


def test_a_cluster_by_address_retries_a_failing_tile_then_names_it(setup, pool, in_process,
                                                                  tmp_path):  # fmt: skip
    # --scheduler: the pool's workers reached through their scheduler's address
    flag = tmp_path / "failed"
    run = run_tiles(setup.plan, FailOnce(setup.job, "r0002c0000", str(flag)), tmp_path / "a",
                    TileSettings(scheduler=pool.address, retries=1, progress=False))  # fmt: skip
    assert flag.exists() and run.scheduler == pool.address
    assert run.workers >= 1  # those up at the start (the nanny may be restarting a killed one)
    assert np.array_equal(_product(setup, run, tmp_path / "ortho.tif"), in_process)
    failed = r"tile r0001c0002 \(rows 256..511, cols 512..\d+\) failed after 2 attempts: OSError"
    with pytest.raises(TileError, match=failed):
        run_tiles(setup.plan, FailOn(setup.job, "r0001c0002"), tmp_path / "b",
                  TileSettings(scheduler=pool.address, retries=1, progress=False))  # fmt: skip
    assert not (tmp_path / "b" / "tiles" / "r0001c0002.json").exists()
