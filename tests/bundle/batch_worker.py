"""Subprocess worker of tests/bundle/test_batch_shard.py (run as a script, not collected).

    python batch_worker.py shard              # 4 forced host devices: sharded vs unsharded
    python batch_worker.py distributed I PORT # process I of 2, coordinator 127.0.0.1:PORT

Prints one JSON line with the max differences of the adjusted parameters and the results.
"""

import json
import os
import sys

MODE = sys.argv[1]
if MODE == "shard":
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4"
    )

import dataclasses  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402

N_PROBLEMS = 8
# least squares: what is tested is the sharding, and one least-squares solve compiles in half
# the time of the robust default's IRLS + final robust solve
LOSS = "l2"


def problems():
    from jaxgeo.bundle._prepare import prepare
    from jaxgeo.io import read_ground, read_observations, read_rpc
    from jaxgeo.models import Biased, ShiftBias
    from jaxgeo.simulate import demo_dir

    folder = demo_dir()
    obs = read_observations(folder / "observations.csv")
    ground = read_ground(folder / "ground.csv").select("gcp")
    keep = [i for i, (p, img) in enumerate(zip(obs.point_ids, obs.images, strict=True))
            if img == "fore" and p in set(ground.ids)]  # fmt: skip
    obs = dataclasses.replace(
        obs,
        point_ids=tuple(obs.point_ids[i] for i in keep),
        images=tuple(obs.images[i] for i in keep),
        xy=obs.xy[keep],
        sigma_px=obs.sigma_px[keep],
    )
    base = prepare(
        {"fore": Biased(read_rpc(folder / "fore.txt"), ShiftBias())}, obs, ground
    ).problem
    xy0 = np.concatenate([np.asarray(ob.xy) for ob in base.images])
    rng = np.random.default_rng(7)
    return [base.with_xy(xy0 + rng.normal(0.0, 0.5, xy0.shape)) for _ in range(N_PROBLEMS)]


def summary(a, b):
    return {
        "theta": float(np.max(np.abs(np.asarray(a.theta[0]) - np.asarray(b.theta[0])))),
        "results_equal": bool(
            np.array_equal(np.asarray(a.result._value), np.asarray(b.result._value))
        ),
        "successful": int(np.sum(np.asarray(a.result._value) == 0)),
    }


def main():
    if MODE == "distributed":
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        jax.distributed.initialize(
            coordinator_address=f"127.0.0.1:{sys.argv[3]}",
            num_processes=2,
            process_id=int(sys.argv[2]),
        )
    from jaxgeo.lsq import SolverConfig, solve_batch
    from jaxgeo.lsq._batch import solve_batch_distributed

    probs, solver = problems(), SolverConfig(loss=LOSS)
    if MODE == "shard":
        out = {"devices": jax.local_device_count()}
        out.update(summary(solve_batch(probs, solver), solve_batch(probs, solver, shard=False)))
    else:
        dist = solve_batch_distributed(probs, solver)
        out = {"processes": jax.process_count()}
        out.update(summary(dist, solve_batch(probs, solver, shard=False)))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
