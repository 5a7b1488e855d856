"""Timing of ``jaxgeo.adjust`` on a synthetic strip (Schur-complement LM vs problem size).

Uses the strip problem of ``benchmarks/peers/strip_synth.py`` (copies of a real Pleiades RPC,
affine bias per scene, tie points with height priors, GCPs in every 4th scene) and reports, per
size, the set-up time, the first call (compilation included) and the best of ``--repeat`` runs
of the compiled solve (:func:`benchmarks.harness.best_of`), as one JSON object per line::

    python -m benchmarks.speed.adjust --scenes 20 80 --ties 50
"""

from __future__ import annotations

import argparse
import json
import os
import time

# threaded OpenBLAS (under jax's LAPACK calls) spin-waits on a busy machine: a 480x480 Cholesky
# took 3 ms single-threaded and up to 230 ms with threads competing for 2 shared cores
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from benchmarks.harness import best_of  # noqa: E402


def to_jaxgeo(problem: dict):
    """The peers' numpy problem -> (models, observations, ground, initial) for jaxgeo.adjust."""
    from jaxgeo import RPC, AffineBias, Biased
    from jaxgeo.io import GroundPoints, Observations

    n_scenes = problem["num"].shape[0]
    names = [f"s{k:03d}" for k in range(n_scenes)]
    models = {
        names[k]: Biased(
            RPC(
                problem["num"][k],
                problem["den"][k],
                problem["ground_offset"][k],
                problem["ground_scale"][k],
                problem["image_offset"][k],
                problem["image_scale"][k],
            ),
            AffineBias(problem["bias0"][k, :2], problem["bias0"][k, 2:].reshape(2, 2)),
        )
        for k in range(n_scenes)
    }
    pids = [f"P{j:05d}" for j in range(problem["points0"].shape[0])]
    obs = Observations(
        tuple(pids[j] for j in problem["obs_point"]),
        tuple(names[k] for k in problem["obs_scene"]),
        np.asarray(problem["obs_xy"], float),
        np.asarray(problem["obs_sigma"], float),
    )
    gp = np.asarray(problem["gcp_point"])
    ground = GroundPoints(
        tuple(pids[j] for j in gp),
        np.asarray(problem["gcp_lonlath"], float),
        ("gcp",) * len(gp),
        np.asarray(problem["gcp_sigma_m"], float),
    )
    initial = {pids[j]: problem["points0"][j] for j in range(len(pids))}
    return models, obs, ground, initial


def run(n_scenes: int, ties: int, repeat: int) -> dict:
    import equinox as eqx

    from benchmarks.peers.strip_synth import make_problem
    from jaxgeo.bundle import AdjustSettings, adjust, prepare
    from jaxgeo.lsq import solve
    from jaxgeo.lsq.internal import describe

    problem = make_problem(n_scenes, ties)
    models, obs, ground, initial = to_jaxgeo(problem)
    t0 = time.perf_counter()
    settings = AdjustSettings(initial=initial)
    setup = prepare(models, obs, ground, settings=settings, check_control=False)
    t_setup = time.perf_counter() - t0
    solve_jit = eqx.filter_jit(solve)
    timing = best_of(lambda: solve_jit(setup.problem), repeat)  # first call: compilation
    sol, t_first, best = timing.out, timing.first_s, timing.best_s
    t0 = time.perf_counter()
    res = adjust(models, obs, ground, settings=settings)
    t_adjust = time.perf_counter() - t0
    return {
        "scenes": n_scenes,
        "tie_points": int(problem["points0"].shape[0]),
        "observations": len(obs.point_ids),
        "unknowns": setup.problem.n_unknowns,
        "setup_s": round(t_setup, 3),
        "first_call_s": round(t_first, 2),
        "jaxgeo_s": round(float(best), 4),
        "adjust_total_s": round(t_adjust, 2),
        "steps": int(sol.num_steps),
        "status": describe(sol.result)[1],
        "cost": float(sol.cost) / 2.0,
        "s0": res.s0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, nargs="+", default=[20, 80])
    parser.add_argument("--ties", type=int, default=50, help="tie points per adjacent pair")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    for n in args.scenes:
        print(json.dumps(run(n, args.ties, args.repeat)), flush=True)


if __name__ == "__main__":
    main()
