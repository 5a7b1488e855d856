"""Subprocess worker of tests/lsq/test_batch_devices.py (run as a script, not collected).

    JAXGEO_CPU_DEVICES=2 python devices_worker.py batch   # solve_batch over the CPU devices
    JAXGEO_CPU_DEVICES=2 python devices_worker.py strip   # Monte-Carlo strips over them

The devices are jaxgeo's default CPU devices (``jaxgeo._runtime.jaxconfig``), here forced to a count
so that the test does not depend on the machine's cores. Prints one JSON line: the devices, and
the largest differences between the sharded results and one device's.
"""

import dataclasses
import json
import sys

import jax  # noqa: E402
import numpy as np  # noqa: E402

import jaxgeo  # noqa: F401  (the CPU devices are set before jax starts)

MODE = sys.argv[1]


def batch_problems(n):
    from jaxgeo.bundle import prepare
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
    base = prepare({"fore": Biased(read_rpc(folder / "fore.txt"), ShiftBias())}, obs, ground)
    xy0 = np.concatenate([np.asarray(ob.xy) for ob in base.problem.images])
    rng = np.random.default_rng(3)
    return [base.problem.with_xy(xy0 + rng.normal(0.0, 0.5, xy0.shape)) for _ in range(n)]


def diff(a, b) -> float:
    leaves = zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    return max(
        float(np.max(np.abs(np.asarray(x, float) - np.asarray(y, float)), initial=0.0))
        for x, y in leaves
    )


def batch():
    from jaxgeo.lsq import SolverConfig, solve_batch
    from jaxgeo.lsq._batch import shard_count

    solver = SolverConfig(loss="l2")  # the sharding is tested; l2 compiles in half the time
    probs = batch_problems(7)  # odd: padded to whole chunks per device
    sharded, single = solve_batch(probs, solver), solve_batch(probs, solver, shard=False)
    return {
        "devices": jax.local_device_count(),
        "shards": shard_count(7),
        "successful": int(np.sum(np.asarray(sharded.result._value) == 0)),
        "results_equal": bool(
            np.array_equal(np.asarray(sharded.result._value), np.asarray(single.result._value))
        ),
        "steps_equal": bool(np.array_equal(sharded.num_steps, single.num_steps)),
        "theta": diff(sharded.theta, single.theta),
        "n": int(np.asarray(sharded.theta[0]).shape[0]),
    }


def strip():
    from jaxgeo.lsq import RESULTS
    from jaxgeo.simulate import Carto2SStripSettings, carto2s_strip
    from jaxgeo.strip import Level2Config, Strip, StripConfig, TieConfig, adjust_strip
    from jaxgeo.strip._batch import monte_carlo_inputs, two_level_sharded
    from jaxgeo.strip._solve import degree_index

    settings = Carto2SStripSettings(gcp_every=1, scene_rows=12000)
    strip = Strip.from_simulation(carto2s_strip(4, seed=3, settings=settings))
    config = StripConfig(ties=TieConfig(per_pair=8), level2=Level2Config("shift"))
    config = dataclasses.replace(
        config, solver=dataclasses.replace(config.solver, loss="l2", remove_blunders=False)
    )
    res = adjust_strip(strip, config)
    xy, gcp_xy, check_xy = monte_carlo_inputs(res, 3, seed=1)  # odd: padded to 4
    args = (res.setup.problem, res.data, xy, gcp_xy, check_xy, degree_index("shift"), config.solver)
    (sol, ev), (sol1, ev1) = two_level_sharded(*args), two_level_sharded(*args, shard=False)
    return {
        "devices": jax.local_device_count(),
        "runs": int(np.asarray(sol.level1.theta[0]).shape[0]),
        "successful": int(np.sum(np.asarray(sol.level1.result == RESULTS.successful))),
        "theta": diff(sol.level1.theta, sol1.level1.theta),
        "evaluation": diff(ev, ev1),
        "runs_differ": float(np.ptp(np.asarray(sol.level1.theta[0])[:, :, 0], axis=0).max()),
    }


if __name__ == "__main__":
    print(json.dumps(batch() if MODE == "batch" else strip()))
