"""Many independent bias adjustments in one call (``jaxgeo.lsq.solve_batch``) against a
loop of compiled single solves, same run.

    python -m benchmarks.speed.batch [--problems 10000] [--loop 200] [--bias shift] [--chunk N]
        [--loss cauchy|huber|l2]

The problem is one image of the embedded demo scene (``jaxgeo demo``: the fore RPC, its 9 GCP
measurements, GCPs as ground control) with an image-space bias; every problem gets its own
Gaussian measurement noise (0.5 px) on the GCPs. Prints one JSON object: ``problems``,
``chunk_max`` (``--chunk``, default jaxgeo's ``default_chunk``: 1000 lanes of balanced chunks
for 10 000 problems), ``jaxgeo_s`` (the batch call after compilation, best of ``--repeats``),
``loop_s`` (a Python loop of ``solve_jit`` over ``--loop`` problems, scaled to ``problems``:
``loop_measured`` says how many were timed), the compile time, the solver steps per problem
(mean, max) and how many problems converged. ``--loss``
(default jaxgeo's, Cauchy): a robust loss iterates (reweighted solves), least squares takes 3
steps on these problems.
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import time

import equinox as eqx
import jax
import numpy as np

import jaxgeo
from benchmarks.harness import best_of, emit
from jaxgeo.bundle import prepare
from jaxgeo.io import read_ground, read_observations, read_rpc
from jaxgeo.lsq import LOSSES, RESULTS, SolverConfig, solve, solve_batch, with_xy_batch
from jaxgeo.lsq._batch import default_chunk
from jaxgeo.models import Biased
from jaxgeo.models.internal import BIAS_KINDS
from jaxgeo.simulate import demo_dir

solve_jit = eqx.filter_jit(solve)
"""A compiled single solve (what ``jaxgeo.lsq._solve.solve_jit`` is, from the public name)."""


def one_image_problem(bias: str):
    folder = demo_dir()
    obs = read_observations(folder / "observations.csv")
    ground = read_ground(folder / "ground.csv").select("gcp")
    gcps = set(ground.ids)
    keep = [i for i, (p, img) in enumerate(zip(obs.point_ids, obs.images, strict=True))
            if img == "fore" and p in gcps]  # fmt: skip
    obs = dataclasses.replace(
        obs,
        point_ids=tuple(obs.point_ids[i] for i in keep),
        images=tuple(obs.images[i] for i in keep),
        xy=obs.xy[keep],
        sigma_px=obs.sigma_px[keep],
    )
    model = Biased(read_rpc(folder / "fore.txt"), BIAS_KINDS[bias]())
    return prepare({"fore": model}, obs, ground).problem


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", type=int, default=10_000)
    parser.add_argument("--loop", type=int, default=200)
    parser.add_argument("--bias", default="shift")
    parser.add_argument("--chunk", type=int, default=None)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--loss", choices=LOSSES, default=SolverConfig().loss)
    args = parser.parse_args()
    solver = SolverConfig(loss=args.loss)

    base = one_image_problem(args.bias)
    xy0 = np.concatenate([np.asarray(ob.xy) for ob in base.images])
    rng = np.random.default_rng(0)
    xy = xy0 + rng.normal(0.0, 0.5, (args.problems, *xy0.shape))
    stacked = with_xy_batch(base, xy)

    # the first call compiles (compile_s), then the best of --repeats
    timing = best_of(lambda: solve_batch(stacked, solver, chunk=args.chunk), args.repeats)
    sol, best, compile_s = timing.out, timing.best_s, timing.first_s

    n_loop = min(args.loop, args.problems)
    noisy = [base.with_xy(xy[k]) for k in range(n_loop)]
    jax.block_until_ready(solve_jit(noisy[0], solver))
    t0 = time.perf_counter()
    singles = [jax.block_until_ready(solve_jit(p, solver)) for p in noisy[:n_loop]]
    loop_s = (time.perf_counter() - t0) * args.problems / n_loop
    diff = max(
        float(np.max(np.abs(np.asarray(sol.theta[0][k]) - np.asarray(s.theta[0]))))
        for k, s in enumerate(singles)
    )
    ok = np.asarray(sol.result._value) == RESULTS.successful._value
    emit(
        {
            "benchmark": "batch_bias_adjustment",
            "problems": args.problems,
            "jaxgeo_s": best,
            "loop_s": loop_s,
            "loop_measured": n_loop,
            "ratio": loop_s / best,
            "compile_s": compile_s,
            "chunk_max": args.chunk or default_chunk(stacked),
            "bias": args.bias,
            "loss": args.loss,
            "steps_mean": float(np.mean(np.asarray(sol.num_steps))),
            "steps_max": int(np.max(np.asarray(sol.num_steps))),
            "gcps_per_problem": int(xy0.shape[0]),
            "converged": int(ok.sum()),
            "max_theta_diff_vs_single": diff,
            "devices": [str(d) for d in jax.devices()],
            "cpu": platform.processor() or platform.machine(),
            "jaxgeo": jaxgeo.__version__,
        }
    )


if __name__ == "__main__":
    main()
