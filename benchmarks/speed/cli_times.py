"""Cold and warm wall times of the CLI: ``jaxgeo demo``, ``jaxgeo adjust`` (the demo data) and
``jaxgeo strip`` (a simulated 80-scene strip), each run as a fresh process.

    python -m benchmarks.speed.cli_times [--scenes 80] [--runs 2] [--skip-strip]

``cold``: an empty compilation cache (a fresh ``JAXGEO_CACHE_DIR``); ``warm``: the best of
``--runs`` further runs on the cache the cold run filled; ``off``: ``JAXGEO_CACHE_DIR=off``
(every run compiles). Prints one JSON object with the wall times (s) and the machine's load
average (the times are of a shared machine when it is high). The strip is simulated once into a
temporary folder (not timed).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import platform
import subprocess
import sys
import tempfile
import time

from benchmarks.data import REPO
from benchmarks.harness import emit


def wall(cmd: list[str], env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    run = subprocess.run(cmd, env=env, capture_output=True, text=True)
    took = time.perf_counter() - t0
    if run.returncode not in (0, 1):  # 1: the solve did not converge (still a timing)
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{run.stderr[-2000:]}")
    return took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=80)
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--skip-strip", action="store_true")
    args = parser.parse_args()

    jaxgeo = [sys.executable, "-m", "jaxgeo.cli"]
    base = dict(os.environ)
    base["PYTHONPATH"] = os.pathsep.join([str(REPO), base.get("PYTHONPATH", "")])
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        demo = REPO / "jaxgeo" / "data" / "cartosat1_demo"
        commands = {
            "demo": [*jaxgeo, "demo"],
            "adjust": [
                *jaxgeo, "adjust", "--image", f"fore={demo / 'fore.txt'}",
                "--image", f"aft={demo / 'aft.txt'}", "--observations",
                str(demo / "observations.csv"), "--ground", str(demo / "ground.csv"),
            ],
        }  # fmt: skip
        if not args.skip_strip:
            strip = tmp / "strip"
            subprocess.run(
                [*jaxgeo, "simulate", "carto2s-strip", "--out", str(strip),
                 "--scenes", str(args.scenes)],
                env=base, check=True, capture_output=True,
            )  # fmt: skip
            commands["strip"] = [*jaxgeo, "strip", str(strip)]
        out = {}
        for name, cmd in commands.items():
            env = dict(base, JAXGEO_CACHE_DIR=str(tmp / f"cache-{name}"))
            cold = wall(cmd, env)
            warm = min(wall(cmd, env) for _ in range(args.runs))
            off = wall(cmd, dict(base, JAXGEO_CACHE_DIR="off"))
            out[name] = {"cold_s": cold, "warm_s": warm, "off_s": off}
    emit(
        {
            "benchmark": "cli_wall_times",
            "results": out,
            "scenes": args.scenes,
            "load_average": os.getloadavg(),
            "cpus": os.cpu_count(),
            "cpu": platform.processor() or platform.machine(),
        }
    )


if __name__ == "__main__":
    main()
