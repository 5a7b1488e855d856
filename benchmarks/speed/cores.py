"""One core against two (or more): the 10 000-problem batch and the 80-scene strip, pinned with
``taskset`` in one run, interleaved.

    python -m benchmarks.speed.cores [--cores 0 0,1] [--rounds 9] [--cases batch strip]
        [--problems 10000] [--scenes 80] [--ties 50] [--loss cauchy]

One worker process per core set (``taskset -c <set> python -m benchmarks.speed.cores
--worker``), each started as a user starts jaxgeo: with its default settings, which give it
one CPU device per core it may use (:mod:`jaxgeo._runtime.jaxconfig`). A core set may carry settings
of its own after a colon (``0,1:JAXGEO_CPU_DEVICES=1``: two cores, one device -- what jax
alone does; several joined by ``+``; ``JAXGEO_BENCH_CODE=DIR``: another checkout's jaxgeo, e.g.
the code before a change); ``--env NAME=VALUE`` applies to every worker. Each worker
builds the cases and compiles them, then times one call whenever the driver asks; the driver
asks the workers in turn, case by case and round by round (the order reversed every other
round), so that both core sets see the same load on a shared machine, and one worker computes
while the other waits.

Cases: ``batch`` is ``benchmarks.speed.batch``'s problem (``jaxgeo.lsq.solve_batch`` of
``--problems`` bias adjustments of the demo's fore image, ``--loss``); ``strip`` is
``benchmarks.speed.strip``'s (the compiled two-level call of an ``--scenes`` Carto-2S strip,
least squares, ``--ties`` per pair). Per case and core set: the wall times (best, median),
the process's CPU time per call and that of its busiest thread (the work a perfect split over
the cores would leave on the critical path: a measure the machine's load barely changes), the
voluntary context switches per call (threads waiting on each other) and the devices; per
case: ``speedup`` = the first core set's time over each other's, the median of the per-round
ratios (and their range, and the ratio of the best times), and both results (to compare).
The load average before and after every round is kept, and ``cores_used_median`` (CPU time
over wall time: the cores a worker actually got). On a loaded machine the wall-time ratios are
lower bounds of a quiet machine's: with Linux's autogroup scheduling (``autogroup`` in the
result) the CPU is shared between sessions, not threads, so a process gets no more than its
session's share however many threads it runs; the critical-path ratio is what two free cores
would give, less the time threads spend waiting on each other.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import subprocess
import sys
import time

import numpy as np

from benchmarks.data import REPO

CODE_ENV = "JAXGEO_BENCH_CODE"
"""A core set's setting (``0,1:JAXGEO_BENCH_CODE=/path/to/checkout``): its worker imports that
checkout's ``jaxgeo`` (the code before a change, compared in the same run)."""


def _log(message: str) -> None:
    print(f"[cores {os.getpid()}] {message}", file=sys.stderr, flush=True)


def thread_cpu_s() -> dict[str, float]:
    """CPU time (user + system, s) of every thread of this process (Linux ``/proc``)."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended
            continue
        out[tid] = (int(fields[11]) + int(fields[12])) / tick
    return out


# --- the worker: one process pinned to one core set ------------------------------------------


def batch_case(problems: int, loss: str):
    """``solve_batch`` of ``problems`` noisy copies of benchmarks.speed.batch's problem."""
    from benchmarks.speed.batch import one_image_problem
    from jaxgeo.lsq import SolverConfig, solve_batch, with_xy_batch

    base = one_image_problem("shift")
    xy0 = np.concatenate([np.asarray(ob.xy) for ob in base.images])
    rng = np.random.default_rng(0)
    stacked = with_xy_batch(base, xy0 + rng.normal(0.0, 0.5, (problems, *xy0.shape)))
    solver = SolverConfig(loss=loss)

    def call():
        return solve_batch(stacked, solver)

    def check(sol) -> list[float]:
        return [float(np.sum(np.asarray(sol.theta[0]))), int(np.sum(np.asarray(sol.num_steps)))]

    return call, check


def strip_case(scenes: int, ties: int):
    """The compiled two-level call of benchmarks.speed.strip's strip."""
    from benchmarks.speed.strip import least_squares_solver, simulate
    from jaxgeo.strip import StripConfig, TieConfig, adjust_strip
    from jaxgeo.strip import _solve as strip_solve

    res = adjust_strip(
        simulate(scenes, 0),
        StripConfig(ties=TieConfig(per_pair=ties), solver=least_squares_solver()),
    )
    c = res.config
    args = (res.setup.problem, res.data, strip_solve.degree_index(c.level2.degree), c.solver)

    def call():
        return strip_solve.two_level_jit(*args)

    def check(sol) -> list[float]:
        return [float(np.sum(np.asarray(sol.level1.theta[0]))), int(sol.level1.num_steps)]

    return call, check


def worker(args) -> None:
    """Build the cases, compile them, then answer the driver: one line in, one JSON line out."""
    import jax

    import jaxgeo  # its CPU-device and cache settings, before jax starts

    cases = {}
    t0 = time.perf_counter()
    if "batch" in args.cases:
        cases["batch"] = batch_case(args.problems, args.loss)
    if "strip" in args.cases:
        cases["strip"] = strip_case(args.scenes, args.ties)
    for call, _ in cases.values():
        jax.block_until_ready(call())  # compilation (or the persistent cache)
    ready = {
        "ready": True,
        "jaxgeo": os.path.dirname(os.path.dirname(jaxgeo.__file__)),
        "devices": jax.local_device_count(),
        "cores_usable": len(os.sched_getaffinity(0)),
        "setup_s": time.perf_counter() - t0,
    }
    print(json.dumps(ready), flush=True)
    for line in sys.stdin:
        name = line.strip()
        if not name:
            break
        call, check = cases[name]
        threads0, usage0 = thread_cpu_s(), resource.getrusage(resource.RUSAGE_SELF)
        t = time.perf_counter()
        out = jax.block_until_ready(call())
        wall = time.perf_counter() - t
        threads1, usage1 = thread_cpu_s(), resource.getrusage(resource.RUSAGE_SELF)
        per_thread = sorted((v - threads0.get(k, 0.0) for k, v in threads1.items()), reverse=True)
        reply = {
            "wall_s": wall,
            "cpu_s": (usage1.ru_utime + usage1.ru_stime) - (usage0.ru_utime + usage0.ru_stime),
            "busiest_thread_cpu_s": per_thread[0] if per_thread else 0.0,
            "voluntary_switches": usage1.ru_nvcsw - usage0.ru_nvcsw,
            "check": check(out),
        }
        print(json.dumps(reply), flush=True)


# --- the driver ------------------------------------------------------------------------------


def start(spec: str, args, env: dict[str, str]) -> subprocess.Popen:
    """The worker of ``spec``: ``CORES[:NAME=VALUE[+NAME=VALUE...]]``."""
    cores, _, extra = spec.partition(":")
    env = dict(env)
    env.update(item.split("=", 1) for item in extra.split("+") if item)
    code = env.pop(CODE_ENV, None)
    run = ["-m", "benchmarks.speed.cores"]
    if code:  # another checkout's jaxgeo (and benchmarks) first; this script as the worker
        env["PYTHONPATH"] = os.pathsep.join([code, str(REPO)])
        run = [str(pathlib.Path(__file__).resolve())]
    cmd = [
        "taskset", "-c", cores, sys.executable, *run, "--worker",
        "--cases", *args.cases, "--problems", str(args.problems), "--scenes", str(args.scenes),
        "--ties", str(args.ties), "--loss", args.loss,
    ]  # fmt: skip
    return subprocess.Popen(
        cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=REPO
    )


def ask(proc: subprocess.Popen, message: str | None = None) -> dict:
    if message is not None:
        proc.stdin.write(message + "\n")
        proc.stdin.flush()
    line = proc.stdout.readline()
    if not line:
        raise RuntimeError(f"worker on cores {proc.args[2]} ended (exit {proc.wait()})")
    return json.loads(line)


def summarize(runs: dict[str, list[dict]], core_sets: list[str]) -> dict:
    base = core_sets[0]
    out: dict = {}
    for cores, rows in runs.items():
        wall = [r["wall_s"] for r in rows]
        out[cores] = {
            "best_s": min(wall),
            "median_s": float(np.median(wall)),
            "cpu_s_median": float(np.median([r["cpu_s"] for r in rows])),
            "busiest_thread_cpu_s_median": float(
                np.median([r["busiest_thread_cpu_s"] for r in rows])
            ),
            "voluntary_switches_median": float(np.median([r["voluntary_switches"] for r in rows])),
            "cores_used_median": float(np.median([r["cpu_s"] / r["wall_s"] for r in rows])),
            "runs_s": wall,
        }
    for cores in core_sets[1:]:
        ratios = [a["wall_s"] / b["wall_s"] for a, b in zip(runs[base], runs[cores], strict=True)]
        cpu_split = (
            out[base]["busiest_thread_cpu_s_median"] / out[cores]["busiest_thread_cpu_s_median"]
        )
        out[f"speedup_{cores}"] = {
            "median_of_round_ratios": float(np.median(ratios)),
            "round_ratios_range": [min(ratios), max(ratios)],
            "ratio_of_best": out[base]["best_s"] / out[cores]["best_s"],
            "ratio_of_medians": out[base]["median_s"] / out[cores]["median_s"],
            "critical_path_ratio": cpu_split,
        }
        # the results (sum of the adjusted parameters, solver steps): one device or several,
        # one thread pool or another, the same to the solver's tolerance (XLA may split a
        # reduction differently for another thread count: rounding)
        a, b = (np.asarray(r["check"], float) for r in (runs[base][-1], runs[cores][-1]))
        out[f"speedup_{cores}"]["results"] = {
            base: a.tolist(),
            cores: b.tolist(),
            "rel_diff": float(np.max(np.abs(a - b) / np.maximum(np.abs(a), 1e-300))),
        }
    return out


def _autogroup() -> bool | None:
    """Whether Linux shares the CPU between sessions (``sched_autogroup_enabled``)."""
    try:
        with open("/proc/sys/kernel/sched_autogroup_enabled") as f:
            return f.read().strip() == "1"
    except OSError:
        return None


def main(argv=None) -> dict | None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--cores", nargs="+", default=["0", "0,1"],
        help="taskset core lists, each optionally with :NAME=VALUE[+NAME=VALUE] settings",
    )  # fmt: skip
    parser.add_argument(
        "--cases", nargs="+", default=["batch", "strip"], choices=["batch", "strip"]
    )
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--problems", type=int, default=10_000)
    parser.add_argument("--scenes", type=int, default=80)
    parser.add_argument("--ties", type=int, default=50)
    parser.add_argument("--loss", default="cauchy")
    parser.add_argument("--env", nargs="*", default=[], help="NAME=VALUE for the workers")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        worker(args)
        return None

    from benchmarks.harness import emit

    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    env.update(item.split("=", 1) for item in args.env)
    t0 = time.perf_counter()
    procs = {cores: start(cores, args, env) for cores in args.cores}
    try:
        ready = {cores: ask(p) for cores, p in procs.items()}
        _log(f"workers ready in {time.perf_counter() - t0:.0f} s: {ready}")
        runs: dict = {case: {cores: [] for cores in procs} for case in args.cases}
        loads = [list(os.getloadavg())]
        for r in range(args.rounds):
            order = list(procs) if r % 2 == 0 else list(procs)[::-1]
            for case in args.cases:
                for cores in order:
                    runs[case][cores].append(ask(procs[cores], case))
            loads.append(list(os.getloadavg()))
            _log(f"round {r + 1}/{args.rounds}: " + ", ".join(
                f"{case} {cores} {runs[case][cores][-1]['wall_s']:.3f} s"
                for case in args.cases for cores in procs
            ))  # fmt: skip
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.stdin.close()
                p.wait(timeout=60)
    result = {
        "core_sets": args.cores,
        "workers": ready,
        "rounds": args.rounds,
        "problems": args.problems,
        "loss": args.loss,
        "scenes": args.scenes,
        "ties_per_pair": args.ties,
        "worker_env": args.env,
        "load_average_1min_by_round": [round(x[0], 2) for x in loads],
        "autogroup": _autogroup(),
        "cases": {case: summarize(runs[case], args.cores) for case in args.cases},
    }
    return emit(result)


if __name__ == "__main__":
    main()
