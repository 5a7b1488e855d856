"""Whole-scene DSM: ``jaxgeo dsm`` tile by tile on a simulated pair, 1 and 2 workers, each a fresh
process tree timed with its peak memory, the result against the simulation's truth.

    python -m benchmarks.speed.dsm_scene --size 6000 --folder /tmp/dsm_6000 [--workers 1 2]

The scene: ``jaxgeo simulate stereo-scene --size N --seed S --exact-rpc`` (a pushbroom pair
rendered through the true physical models over a textured synthetic terrain, RPCs fitted to the
exact models: the vendor's pointing error, which shifts every height alike until an adjustment
with GCPs removes it, is left out so that the numbers are the DSM chain's). jaxgeo runs as users
run it: ``jaxgeo dsm left.tif right.tif --res R -o dsm.tif --workers W`` (no ROI: the whole
scene, tiles of 1024 cells, a COG with the five bands), after one warm-up run of a 1000 px ROI
that fills the compilation cache. Memory and CPU as :mod:`benchmarks.speed.ortho_scene`
measures them (the sum over the process tree, dask's scheduler, nannies and workers included).
Accuracy: the DSM against ``truth_dsm.tif`` on the DSM's cells (nearest truth cell): median and
NMAD of the height error, the share of the truth's cells with a height (fill), and between the
worker counts the largest difference (the same tiles: equal to float32 rounding).

Per stage (``stages``): the wall and CPU seconds each tile's work spent in each stage of the chain
(:data:`jaxgeo.stereo._stages.STAGES`: SIFT, ties, rectification, resampling, SGM, refinement,
triangulation, sigma, rasterisation, writing; the tiles' ``stages_s``), summed over the tiles,
with each stage's share of the tiles' CPU seconds, and the share of the dense matcher (SGM and
its refinement). ``--jaxgeo DIR`` times another checkout of jaxgeo (e.g. the main branch, for a
before/after in one run; a tree without the per-stage times reports none).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys

from benchmarks.data import REPO
from benchmarks.harness import emit
from benchmarks.speed.ortho_scene import measure


def _on_grid(grid_path, path):
    import numpy as np
    import rasterio
    from rasterio.warp import Resampling, reproject

    with rasterio.open(grid_path) as g, rasterio.open(path) as s:
        out = np.full((g.height, g.width), np.nan)
        reproject(rasterio.band(s, 1), out, dst_transform=g.transform, dst_crs=g.crs,
                  resampling=Resampling.nearest, src_nodata=np.nan, dst_nodata=np.nan)  # fmt: skip
    return out


def accuracy(dsm_path, truth_path) -> dict:
    """The DSM's height error against the truth on the DSM's cells."""
    import numpy as np

    h = _on_grid(dsm_path, dsm_path)
    truth = _on_grid(dsm_path, truth_path)
    seen = np.isfinite(truth)
    ok = seen & np.isfinite(h)
    dh = h[ok] - truth[ok]
    med = float(np.median(dh))
    return {"fill_of_truth": float(ok.sum() / max(seen.sum(), 1)),
            "median_abs_dh_m": float(np.median(np.abs(dh))), "median_dh_m": med,
            "nmad_m": float(1.4826 * np.median(np.abs(dh - med))),
            "p95_abs_dh_m": float(np.percentile(np.abs(dh), 95))}  # fmt: skip


def _max_diff(a_path, b_path) -> float:
    import numpy as np

    a, b = _on_grid(a_path, a_path), _on_grid(a_path, b_path)
    both = np.isfinite(a) & np.isfinite(b)
    return float(np.max(np.abs(a[both] - b[both]), initial=0.0))


def stage_shares(tile_stats: dict) -> dict | None:
    """The tiles' ``stages_s`` summed (wall and CPU s per stage), each stage's share of the
    CPU seconds, and the dense matcher's (SGM and refinement); ``None`` without them."""
    wall, cpu = {}, {}
    tiles = 0
    for stats in tile_stats.values():
        stages = stats.get("stages_s") if isinstance(stats, dict) else None
        if not stages:
            continue
        tiles += 1
        for name, t in stages.items():
            wall[name] = wall.get(name, 0.0) + t["wall_s"]
            cpu[name] = cpu.get(name, 0.0) + t["cpu_s"]
    if not tiles:
        return None
    total = sum(cpu.values())
    return {
        "tiles": tiles,
        "wall_s": {k: round(v, 2) for k, v in wall.items()},
        "cpu_s": {k: round(v, 2) for k, v in cpu.items()},
        "cpu_share": {k: round(v / total, 3) for k, v in cpu.items()},
        "tiles_cpu_s": round(total, 2),
        "dense_matcher_cpu_share": round((cpu.get("sgm", 0) + cpu.get("refinement", 0)) / total, 3),
        "sgm_cpu_share": round(cpu.get("sgm", 0) / total, 3),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=2000, help="scene size (px, square)")
    p.add_argument("--seed", type=int, default=7, help="simulation seed")
    p.add_argument("--folder", required=True, help="where the scene and the outputs go")
    p.add_argument("--res", type=float, default=None, help="DSM cells, m (default: the GSD)")
    p.add_argument("--workers", type=int, nargs="*", default=[1, 2],
                   help="jaxgeo worker counts to time (0: in this process)")  # fmt: skip
    p.add_argument("--jaxgeo", default=None,
                   help="the checkout of jaxgeo to time (default: this one)")  # fmt: skip
    p.add_argument("--tag", default="", help="suffix of the output names (two trees, one folder)")
    a = p.parse_args(argv)
    folder = pathlib.Path(a.folder)
    env = dict(os.environ)
    tree = pathlib.Path(a.jaxgeo).resolve() if a.jaxgeo else REPO
    env["PYTHONPATH"] = os.pathsep.join([str(tree), env.get("PYTHONPATH", "")])
    # -P: not the working directory's jaxgeo first (--jaxgeo names the tree)
    cli = [sys.executable, "-P", "-m", "jaxgeo.cli"]
    scene = folder / "scene"
    if not (scene / "truth.json").exists():
        simulate = [*cli, "simulate", "stereo-scene", "--size", str(a.size), "--seed",
                    str(a.seed), "--exact-rpc", "--quiet", "--json", "-o", str(scene)]  # fmt: skip
        sim = measure(simulate, env)
    else:
        sim = None
    truth = json.loads((scene / "truth.json").read_text())
    gsd = float(truth["gsd_m"])
    res = a.res or round(gsd, 2)
    left, right = str(scene / "left.tif"), str(scene / "right.tif")
    dsm = [*cli, "dsm", left, right, "--res", str(res), "--quiet", "--json", "--overwrite"]
    roi = min(1000, a.size)
    first = measure([*dsm, "--roi", "0", "0", str(roi), str(roi), "-o",
                     str(folder / f"warmup{a.tag}.tif")], env)  # fmt: skip
    result = {
        "scene": f"jaxgeo simulate stereo-scene --size {a.size} --seed {a.seed} --exact-rpc "
                 f"(GSD {gsd:.3f} m), DSM at {res} m",
        "jaxgeo_tree": str(tree),
        "simulate_s": None if sim is None else sim["wall_s"],
        "warmup_roi_px": roi,
        "warmup_s": first["wall_s"],
    }  # fmt: skip
    runs = {}
    for w in a.workers:
        out = folder / f"dsm_workers{w}{a.tag}.tif"
        m = measure([*dsm, "--workers", str(w), "-o", str(out)], env)
        report = json.loads(m.pop("stdout").splitlines()[-1])
        m["report"] = report
        cells = report["shape"][0] * report["shape"][1]
        m["mcells_per_s"] = cells / 1e6 / m["wall_s"]
        m["scene_mpx_per_s"] = a.size * a.size / 1e6 / m["wall_s"]
        m["load_average"] = [round(x, 2) for x in os.getloadavg()]
        m["accuracy"] = accuracy(out, scene / "truth_dsm.tif")
        m["stages"] = stage_shares(report.get("tile_stats") or {})
        runs[f"workers{w}"] = m
    result["jaxgeo"] = runs
    names = list(runs)
    if len(names) > 1:
        a0 = folder / f"dsm_{names[0]}{a.tag}.tif"
        result["max_abs_difference_between_worker_counts_m"] = max(
            _max_diff(a0, folder / f"dsm_{n}{a.tag}.tif") for n in names[1:]
        )
    if "workers1" in runs and "workers2" in runs:
        result["scaling_1_to_2_workers"] = runs["workers1"]["wall_s"] / runs["workers2"]["wall_s"]
    best = min(runs.values(), key=lambda m: m["wall_s"])
    per_mpx = best["wall_s"] / (a.size * a.size / 1e6)
    result["extrapolation_40000px_16cores_h"] = {
        "assumes": "time linear in area (tiles), the best run's s/Mpx, 16 workers at the "
                   "measured 1->2 scaling per doubling (4 doublings from 1 worker)",
        "s_per_mpx_best": per_mpx,
    }  # fmt: skip
    if "scaling_1_to_2_workers" in result:
        one = runs["workers1"]["wall_s"] / (a.size * a.size / 1e6)
        speedup = result["scaling_1_to_2_workers"] ** 4
        result["extrapolation_40000px_16cores_h"]["hours"] = one * 1600 / speedup / 3600
    result["note"] = (
        "wall and CPU seconds of a fresh process tree each (the command, its dask scheduler, "
        "nannies and workers); the machine is shared: see load_average; accuracy against the "
        "simulation's truth DSM (exact RPCs: no vendor pointing error)"
    )
    emit(result, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
