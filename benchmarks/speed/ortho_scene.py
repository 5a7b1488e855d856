"""Whole-scene orthorectification: ``jaxgeo ortho`` (1 and 2 workers, and in this process) against
GDAL's warper with RPCs and a DEM on the same grid, each a fresh process tree timed with its peak
memory.

    python -m benchmarks.speed.ortho_scene --size 12000 --folder /tmp/ortho_12000 [--workers 1 2]
    python -m benchmarks.speed.ortho_scene --size 1000 --folder /tmp/ortho_1000 --cold --auto \
        --workers --repeat 5 [--baseline main]   # a small product: cold, warm, GDAL (, before)

``--cold``: the warm-up run starts from an empty compilation cache of its own
(``JAXGEO_CACHE_DIR=FOLDER/cache``, emptied first), so ``first_run_s`` is a first run on a new
machine (every program traced and compiled), and every later run is warm (programs loaded from
that cache, nothing traced); ``ratio_first_vs_gdal_cog`` then compares that cold run with GDAL.
``--baseline REF``: jaxgeo at the git commit ``REF`` of this repository (``git archive`` into
``FOLDER/baseline-REF``) is timed too, as the case ``baseline`` (its default settings, like
``auto``), in the same rounds, with a cache of its own (``FOLDER/cache-baseline``, emptied
under ``--cold``): before and after a change, under the same load.

Python's bytecode: the commands run without ``PYTHONDONTWRITEBYTECODE`` and each jaxgeo tree
timed is byte-compiled first (``compileall``, as ``pip install`` does): with that variable set
(as on some development machines) every run compiled jaxgeo's ~100 modules from source again,
~0.2 s of CPU a run that no installed jaxgeo pays (site-packages, GDAL's Python side included,
hold their bytecode already).

The scene (:mod:`benchmarks.speed.ortho_data`): an N x N px uint16 crop of the Ventoux Pleiades
product with its RPC in the tags, SRTM + EGM96 as an ellipsoidal DEM. jaxgeo runs as users run it
(``jaxgeo ortho scene.tif --dem dem.tif -o out.tif --workers W``: COG, DEFLATE, overviews) after
one warm-up run that fills the compilation cache (its time is reported as ``first_run_s``). GDAL
is ``rasterio.warp.reproject`` file to file with ``rpcs=``, ``RPC_DEM=`` and ``num_threads`` =
cores: GDAL's multi-threaded ``ChunkAndWarpMulti``, what ``gdalwarp -rpc -to RPC_DEM=dem.tif
-multi -wo NUM_THREADS=ALL_CPUS`` runs (no ``gdalwarp`` binary here), bilinear, onto jaxgeo's
grid, written as an uncompressed tiled GeoTIFF (``gdal_gtiff``) and, like jaxgeo's output,
then copied into a DEFLATE COG with overviews (``gdal_cog``). Memory: the peak over the run of
the sum over the process tree (the command and every descendant, dask workers included) of RSS
and of PSS (shared pages split between the processes that map them: the fair sum); sampled every
0.2 s with psutil. CPU: user + system seconds of the tree (``RUSAGE_CHILDREN``). The cases run
round robin, ``--repeat`` rounds, the best wall time of each kept (a shared machine: the least
disturbed run). Ratios are GDAL's wall time over jaxgeo's, same run (> 1: jaxgeo is faster).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import subprocess
import sys
import threading
import time

from benchmarks.data import REPO
from benchmarks.harness import emit

PEER = """
import sys, rasterio, rasterio.shutil
from rasterio.warp import reproject, Resampling
scene, dem, like, out, threads, cog = sys.argv[1:7]
with rasterio.open(scene) as src, rasterio.open(like) as ref:
    profile = dict(driver="GTiff", width=ref.width, height=ref.height, count=src.count,
                   dtype=src.dtypes[0], crs=ref.crs, transform=ref.transform, nodata=0,
                   tiled=True, blockxsize=256, blockysize=256, BIGTIFF="IF_SAFER")
    with rasterio.open(out, "w", **profile) as dst:
        for b in range(1, src.count + 1):
            reproject(rasterio.band(src, b), rasterio.band(dst, b), rpcs=src.rpcs,
                      src_crs="EPSG:4326", resampling=Resampling.bilinear, RPC_DEM=dem,
                      num_threads=int(threads), dst_nodata=0)
if cog == "1":
    with rasterio.Env(GDAL_NUM_THREADS="ALL_CPUS"):
        rasterio.shutil.copy(out, out + ".cog.tif", driver="COG", COMPRESS="DEFLATE", LEVEL=1,
                             PREDICTOR=2, OVERVIEWS="AUTO", RESAMPLING="AVERAGE",
                             NUM_THREADS="ALL_CPUS", BIGTIFF="IF_SAFER", BLOCKSIZE=512)
"""


def _tree_memory(pid: int) -> tuple[int, int]:
    """``(rss, pss)`` bytes summed over process ``pid`` and its descendants."""
    import psutil

    try:
        root = psutil.Process(pid)
        procs = [root, *root.children(recursive=True)]
    except psutil.Error:
        return 0, 0
    rss = pss = 0
    for p in procs:
        try:
            full = p.memory_full_info()
            rss += full.rss
            pss += getattr(full, "pss", full.rss)
        except psutil.Error:
            continue
    return rss, pss


def measure(cmd: list[str], env: dict | None = None, interval: float = 0.2, cwd=None) -> dict:
    """Run ``cmd`` (in ``cwd``); its wall time, CPU time and the peak memory of its process
    tree."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=cwd)  # fmt: skip
    peak = [0, 0]
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            rss, pss = _tree_memory(proc.pid)
            peak[0], peak[1] = max(peak[0], rss), max(peak[1], pss)
            stop.wait(interval)

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    out, err = proc.communicate()
    wall = time.perf_counter() - t0
    stop.set()
    thread.join()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{err[-3000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "peak_rss_gb": peak[0] / 1e9,
            "peak_pss_gb": peak[1] / 1e9, "stdout": out.strip()}  # fmt: skip


def _mean_abs_diff(a_path, b_path) -> dict:
    import numpy as np
    import rasterio

    with rasterio.open(a_path) as a, rasterio.open(b_path) as b:
        assert a.shape == b.shape and a.transform == b.transform
        diffs, both, only_a, only_b, n = [], 0, 0, 0, 0
        for _, win in a.block_windows(1):
            x = a.read(1, window=win).astype(float)
            y = b.read(1, window=win).astype(float)
            ok = (x > 0) & (y > 0)
            diffs.append(np.abs(x - y)[ok].sum())
            both += int(ok.sum())
            only_a += int(((x > 0) & ~(y > 0)).sum())
            only_b += int((~(x > 0) & (y > 0)).sum())
            n += x.size
    return {"mean_abs_diff_dn": float(sum(diffs) / max(both, 1)), "both_valid": both / n,
            "only_jaxgeo": only_a / n, "only_gdal": only_b / n}  # fmt: skip


def baseline_tree(ref: str, folder: pathlib.Path) -> pathlib.Path:
    """jaxgeo's package at git commit ``ref`` of this repository, exported (``git archive``)
    into ``folder/baseline-<ref>`` (replaced): the tree a baseline case runs."""
    import shutil

    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in ref)
    tree = folder / f"baseline-{safe}"
    shutil.rmtree(tree, ignore_errors=True)
    tree.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", ref, "jaxgeo"], check=True,
                             capture_output=True).stdout  # fmt: skip
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return tree


def byte_compile(tree: pathlib.Path) -> None:
    """``tree``'s jaxgeo package byte-compiled, as an installed package is."""
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "jaxgeo")], check=True,
                   stdout=subprocess.DEVNULL)  # fmt: skip


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=2000, help="scene size (px, square)")
    p.add_argument("--folder", required=True, help="where the scene and the outputs go")
    p.add_argument("--workers", type=int, nargs="*", default=[1, 2],
                   help="jaxgeo worker counts to time (0: in this process)")  # fmt: skip
    p.add_argument("--auto", action="store_true", help="also time jaxgeo's default (no --workers)")
    p.add_argument("--no-gdal", action="store_true", help="skip the GDAL peer")
    p.add_argument("--compress", default="deflate", help="jaxgeo's COG compression")
    p.add_argument("--repeat", type=int, default=1, help="rounds of every case (best kept)")
    p.add_argument("--cold", action="store_true",
                   help="the first run on an empty cache of its own (FOLDER/cache)")  # fmt: skip
    p.add_argument("--baseline", metavar="REF",
                   help="also time jaxgeo at git commit REF (e.g. main), same rounds")  # fmt: skip
    a = p.parse_args(argv)
    from benchmarks.speed.ortho_data import make_scene

    folder = pathlib.Path(a.folder)
    scene, dem = make_scene(folder, a.size)
    peer_env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    # ``-m jaxgeo.cli`` imports jaxgeo from the working directory first: each tree runs in its own
    trees = {"": REPO}
    if a.baseline:
        trees["baseline"] = baseline_tree(a.baseline, folder)
    envs = {}
    for name, tree in trees.items():
        byte_compile(tree)
        env = dict(peer_env)
        env["PYTHONPATH"] = os.pathsep.join([str(tree), env.get("PYTHONPATH", "")])
        cache = folder / ("cache" if not name else f"cache-{name}")
        if a.cold:  # a cache of its own, empty: the first run traces and compiles everything
            import shutil

            shutil.rmtree(cache, ignore_errors=True)
        if a.cold or name:
            env["JAXGEO_CACHE_DIR"] = str(cache)
        envs[name] = env
    env = envs[""]
    jaxgeo = [sys.executable, "-m", "jaxgeo.cli", "ortho", str(scene), "--dem", str(dem),
              "--quiet", "--json", "--overwrite", "--compress", a.compress]  # fmt: skip
    first = measure([*jaxgeo, "-o", str(folder / "warmup.tif"), "--workers", "0"], env, cwd=REPO)
    report = json.loads(first["stdout"].splitlines()[-1])
    result = {
        "scene": f"{a.size} x {a.size} px uint16 crop of the Ventoux Pleiades product (RPC in "
                 "the tags), SRTM 90 m + EGM96 ellipsoidal DEM, bilinear",
        "output_px": [report["height"], report["width"]],
        "output_mpx": report["width"] * report["height"] / 1e6,
        "tiles": report["tiles"],
        "first_run_s": first["wall_s"],
        "first_run_cold": a.cold,
    }  # fmt: skip
    if a.baseline:
        base_first = measure([*jaxgeo, "-o", str(folder / "warmup_baseline.tif"), "--workers",
                              "0"], envs["baseline"], cwd=trees["baseline"])  # fmt: skip
        result["baseline"] = a.baseline
        result["baseline_first_run_s"] = base_first["wall_s"]
    threads = str(len(os.sched_getaffinity(0)))
    like = folder / "warmup.tif"  # jaxgeo's grid, for GDAL
    cases = [("auto", [])] if a.auto else []
    cases += [(f"workers{w}", ["--workers", str(w)]) for w in a.workers]
    if a.baseline:
        cases.append(("baseline", []))
    commands = {name: [*jaxgeo, "-o", str(folder / f"jaxgeo_{name}.tif"), *extra]
                for name, extra in cases}  # fmt: skip
    where = {name: "baseline" if name == "baseline" else "" for name in commands}
    if not a.no_gdal:
        for name, cog in (("gdal_gtiff", "0"), ("gdal_cog", "1")):
            commands[name] = [sys.executable, "-c", PEER, str(scene), str(dem), str(like),
                              str(folder / f"{name}.tif"), threads, cog]  # fmt: skip
            where[name] = None
    # round robin, best of --repeat: on a shared machine every case meets the same load
    all_runs = {name: [] for name in commands}
    for _ in range(a.repeat):
        for name, cmd in commands.items():
            tree = where[name]
            m = (measure(cmd, peer_env) if tree is None
                 else measure(cmd, envs[tree], cwd=trees[tree]))  # fmt: skip
            out = m.pop("stdout")
            if not name.startswith("gdal"):
                m["report"] = json.loads(out.splitlines()[-1])
            m["mpx_per_s"] = result["output_mpx"] / m["wall_s"]
            m["load_average"] = [round(x, 2) for x in os.getloadavg()]
            all_runs[name].append(m)
    best = {name: min(ms, key=lambda m: m["wall_s"]) for name, ms in all_runs.items()}
    every = {name: {"walls_s": [m["wall_s"] for m in ms], "cpus_s": [m["cpu_s"] for m in ms]}
             for name, ms in all_runs.items()}  # fmt: skip
    runs = {name: {**best[name], **every[name]} for name, _ in cases}
    result["jaxgeo"] = runs
    if not a.no_gdal:
        peers = {name: {**best[name], **every[name]} for name in ("gdal_gtiff", "gdal_cog")}
        result["gdal"] = peers
        result["gdal_threads"] = int(threads)
        result["agreement_vs_gdal"] = _mean_abs_diff(like, folder / "gdal_gtiff.tif")
        for m in runs.values():
            m["ratio_vs_gdal_gtiff"] = peers["gdal_gtiff"]["wall_s"] / m["wall_s"]
            m["ratio_vs_gdal_cog"] = peers["gdal_cog"]["wall_s"] / m["wall_s"]
            m["cpu_ratio_vs_gdal_gtiff"] = peers["gdal_gtiff"]["cpu_s"] / m["cpu_s"]
            # the least CPU time of any round, each: less disturbed by the load than one round's
            m["min_cpu_ratio_vs_gdal_cog"] = min(peers["gdal_cog"]["cpus_s"]) / min(m["cpus_s"])
        result["ratio_first_vs_gdal_cog"] = peers["gdal_cog"]["wall_s"] / first["wall_s"]
    if "baseline" in runs and "auto" in runs:
        result["speedup_vs_baseline"] = runs["baseline"]["wall_s"] / runs["auto"]["wall_s"]
        result["cpu_speedup_vs_baseline"] = min(runs["baseline"]["cpus_s"]) / min(
            runs["auto"]["cpus_s"]
        )
    if "workers1" in runs and "workers2" in runs:
        result["scaling_1_to_2_workers"] = runs["workers1"]["wall_s"] / runs["workers2"]["wall_s"]
    result["note"] = (
        "wall and CPU seconds of a fresh process tree each (the command, its dask scheduler, "
        "nannies and workers); jaxgeo writes a DEFLATE COG with overviews, gdal_gtiff an "
        "uncompressed tiled GeoTIFF, gdal_cog the same then a DEFLATE COG; ratio: GDAL's wall "
        "time over jaxgeo's (> 1: jaxgeo faster); the cases run round robin, --repeat rounds, the "
        "best wall time kept (walls_s, cpus_s: every round; min_cpu_ratio_vs_gdal_cog and "
        "cpu_speedup_vs_baseline: the least CPU time of each); the machine is shared: see "
        "load_average; bytecode compiled (no PYTHONDONTWRITEBYTECODE), as installed"
        + ("; first_run_s: cold, an empty compilation cache (every later run warm)"
           if a.cold else "")
    )  # fmt: skip
    emit(result, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
