"""One path for every tiled product (``jaxgeo.tiles.make_product``): the tiles run, the COG
written atomically, the work folder removed after success and kept (``resume``) after a
failure, the totals of the typed per-tile statistics (``TileStats``), a product without data
refused before anything is written, ``TileSettings.plan`` writing the plan only."""

import dataclasses
import json

import numpy as np
import pytest
import rasterio

from jaxgeo.tiles import (
    EmptyProduct,
    RasterSpec,
    TileError,
    TileSettings,
    TileStats,
    make_product,
    plan_tiles,
)
from jaxgeo.tiles.internal import NoData, write_tile

SPEC = RasterSpec(1, "float32", float("nan"), "EPSG:32631", (1.0, 0.0, 500_000.0, 0.0, -1.0,
                  5_000_000.0))  # fmt: skip
HERE = TileSettings(workers=0, progress=False)


@dataclasses.dataclass(frozen=True)
class Ramp:
    """Writes ``row + col`` in each tile's window (NaN in its first row) with its counters; no
    data for the tiles in ``empty``; fails on tile ``fail``."""

    empty: tuple = ()
    fail: str = ""

    def __call__(self, tile, path):
        if tile.id in self.empty:
            raise NoData(f"nothing in {tile.id}")
        if tile.id == self.fail:
            raise OSError("disk on fire")
        r, c = np.mgrid[tile.row : tile.row + tile.rows, tile.col : tile.col + tile.cols]
        data = (r + c).astype("float32")
        data[0] = np.nan
        write_tile(path, SPEC, tile.row, tile.col, data[None])
        return {"valid_px": int(np.isfinite(data).sum()), "filled_px": 1, "blocks": 4,
                "refined_blocks": 1, "grid_error_px": 0.001 * tile.row,
                "note": tile.id}  # fmt: skip


def test_stats_sum_counters_and_keep_the_largest_error():
    a = TileStats.from_dict({"valid_px": 3, "blocks": 2, "grid_error_px": 0.5, "pairs": [1]})
    b = TileStats.from_dict({"valid_px": 4, "occluded_px": 1, "grid_error_px": 0.2})
    assert a.details == {"pairs": [1]}
    assert a.as_dict() == {"valid_px": 3, "blocks": 2, "grid_error_px": 0.5, "pairs": [1]}
    total = TileStats.total([a, b])
    assert (total.valid_px, total.blocks, total.occluded_px) == (7, 2, 1)
    assert total.grid_error_px == 0.5 and total.details == {}
    assert total.as_dict() == {"valid_px": 7, "occluded_px": 1, "blocks": 2, "grid_error_px": 0.5}
    assert TileStats.from_dict({"no_data": "water"}).as_dict() == {"no_data": "water"}
    assert TileStats.total([]) == TileStats()


def test_product_of_its_tiles_and_their_totals(tmp_path):
    plan = plan_tiles("demo", 50, 40, 16)
    out = tmp_path / "ramp.tif"
    product = make_product(plan, Ramp(empty=("r0000c0000",)), out, SPEC, HERE)
    assert product.path == out and product.tiles == len(plan) == 12 and product.empty_tiles == 1
    assert product.stats["r0000c0000"].no_data == "nothing in r0000c0000"
    assert product.stats["r0001c0001"].details == {"note": "r0001c0001"}
    with rasterio.open(out) as ds:
        data = ds.read(1)
    assert product.total.valid_px == int(np.isfinite(data).sum())
    assert product.total.filled_px == 11 and product.total.blocks == 44
    assert product.total.grid_error_px == pytest.approx(0.032)
    r, c = np.mgrid[0:40, 0:50]
    ok = np.isfinite(data)
    assert np.array_equal(data[ok], (r + c)[ok]) and np.isnan(data[:16, :16]).all()
    assert [p.name for p in tmp_path.iterdir()] == ["ramp.tif"]  # the work folder is gone
    with pytest.raises(FileExistsError):  # refused before any tile runs
        make_product(plan, Ramp(fail="r0000c0000"), out, SPEC, HERE)


def test_a_failed_run_keeps_its_resume_folder_for_the_next(tmp_path):
    plan = plan_tiles("demo", 50, 40, 16)
    work = tmp_path / "work"
    keep = dataclasses.replace(HERE, resume=work, retries=0)
    with pytest.raises(TileError, match="r0002c0003"):
        make_product(plan, Ramp(fail="r0002c0003"), tmp_path / "a.tif", SPEC, keep)
    assert not (tmp_path / "a.tif").exists() and len(list((work / "tiles").glob("*.tif"))) == 11
    product = make_product(plan, Ramp(), tmp_path / "a.tif", SPEC, keep)
    assert product.reused_tiles == 11 and not work.exists()


def test_no_data_anywhere_is_refused_and_nothing_is_written(tmp_path):
    plan = plan_tiles("demo", 20, 20, 16)
    with pytest.raises(EmptyProduct) as err:
        make_product(plan, Ramp(empty=tuple(t.id for t in plan.tiles)), tmp_path / "e.tif",
                     SPEC, HERE)  # fmt: skip
    assert err.value.reasons()[0] == "nothing in r0000c0000"
    assert list(tmp_path.iterdir()) == []


def test_plan_only(tmp_path):
    plan = plan_tiles("demo", 50, 40, 16)
    settings = dataclasses.replace(HERE, plan=tmp_path / "plan.json")
    product = make_product(plan, Ramp(fail="r0000c0000"), tmp_path / "x.tif", SPEC, settings)
    assert product.path is None and product.run is None and not (tmp_path / "x.tif").exists()
    assert json.loads((tmp_path / "plan.json").read_text())["n_tiles"] == 12
