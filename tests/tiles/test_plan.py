"""Tile plans: a partition of the product, ids, JSON round trip, fingerprints, bad files."""

import json

import numpy as np
import pytest

from jaxgeo.tiles import PlanError, TilePlan, plan_tiles, read_plan, write_plan


@pytest.mark.parametrize("width,height,tile", [(1, 1, 7), (300, 250, 100), (1024, 1000, 256)])
def test_tiles_cover_the_product_once(width, height, tile):
    plan = plan_tiles("demo", width, height, tile)
    seen = np.zeros((height, width), dtype=int)
    for t in plan.tiles:
        assert 1 <= t.rows <= tile and 1 <= t.cols <= tile
        seen[t.row : t.row + t.rows, t.col : t.col + t.cols] += 1
    assert np.all(seen == 1)
    assert len({t.id for t in plan.tiles}) == len(plan) == -(-width // tile) * -(-height // tile)


def test_json_round_trip_and_fingerprint(tmp_path):
    plan = plan_tiles("demo", 300, 250, 100, margin_px=4, job={"image": "a.tif", "res": 0.5},
                      inputs=lambda t: {"window": [t.col, t.row, t.cols, t.rows]})  # fmt: skip
    path = write_plan(plan, tmp_path / "plan.json")
    back = read_plan(path)
    assert back == plan and back.fingerprint() == plan.fingerprint()
    assert back.tile("r0001c0002").inputs == {"window": [200, 100, 100, 100]}
    data = json.loads(path.read_text())
    assert data["n_tiles"] == 9 and data["job"]["res"] == 0.5
    other = plan_tiles("demo", 300, 250, 100, margin_px=4, job={"image": "a.tif", "res": 1.0},
                       inputs=lambda t: {"window": [t.col, t.row, t.cols, t.rows]})  # fmt: skip
    assert other.fingerprint() != plan.fingerprint()
    with pytest.raises(FileExistsError):
        write_plan(plan, path)


def test_bad_plans_are_named(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(PlanError, match="bad.json: not JSON"):
        read_plan(bad)
    bad.write_text(json.dumps({"format": "something/9"}))
    with pytest.raises(PlanError, match="not a jaxgeo tile plan"):
        read_plan(bad)
    with pytest.raises(PlanError, match="empty product"):
        plan_tiles("demo", 0, 10, 4)
    with pytest.raises(PlanError, match="repeat"):
        plan = plan_tiles("demo", 8, 8, 4)
        TilePlan("demo", 8, 8, 4, 0, plan.tiles + plan.tiles[:1])
