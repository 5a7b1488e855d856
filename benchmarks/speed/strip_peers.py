"""The strip peers alone (scipy, Ceres) on a synthetic strip problem: times, costs, iterations.

    python -m benchmarks.speed.strip_peers --scenes 80 --ties 50 [--peers scipy ceres]

prints one JSON object (the machine last: :func:`benchmarks.harness.emit`) with each peer's
time, cost, evaluations and largest bias error (px at the image corners) on the problem of
:mod:`benchmarks.peers.strip_synth`, and its agreement with the first peer listed. The peers
against jaxgeo on jaxgeo's own strip: ``python -m benchmarks.speed.strip``.
"""

from __future__ import annotations

import argparse

from benchmarks.harness import emit
from benchmarks.peers.strip import (
    Layout,
    bias_effect_px,
    cost,
    solve_ceres,
    solve_scipy,
    validate,
)
from benchmarks.peers.strip_synth import make_problem


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=80)
    parser.add_argument("--ties", type=int, default=50, help="tie points per adjacent pair")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--peers", nargs="+", default=["scipy", "ceres"],
                        choices=["scipy", "scipy-analytic", "ceres"])  # fmt: skip
    parser.add_argument("--max-nfev", type=int, default=200)
    parser.add_argument("--lsmr-tol", type=float, default=1e-10, help="for scipy-analytic")
    args = parser.parse_args(argv)
    problem = make_problem(args.scenes, args.ties, args.seed)
    layout = Layout.of(validate(problem))
    out: dict = {"scenes": layout.n_scenes, "unknowns": layout.n_unknowns,
                 "observations": layout.n_obs, "residuals": layout.n_residuals,
                 "initial_cost": cost(problem, problem["bias0"], problem["points0"])}  # fmt: skip
    first = None
    for peer in args.peers:
        if peer == "ceres":
            res = solve_ceres(problem)
        else:
            analytic = peer == "scipy-analytic"
            res = solve_scipy(
                problem, max_nfev=args.max_nfev, jac="analytic" if analytic else "2-point",
                lsmr_tol=args.lsmr_tol if analytic else None,
            )  # fmt: skip
        key = peer.replace("-", "_")
        for k, v in res.items():
            if k not in ("bias", "points"):
                out[f"{key}_{k}"] = v
        out[f"{key}_bias_error_px_max"] = float(
            bias_effect_px(problem, res["bias"], problem["bias_true"]).max()
        )
        first = first or (key, res)
        if first[0] != key:  # agreement with the first peer listed
            out[f"{key}_cost_rel_to_{first[0]}"] = (res["cost"] - first[1]["cost"]) / res["cost"]
            out[f"{key}_bias_vs_{first[0]}_px_max"] = float(
                bias_effect_px(problem, res["bias"], first[1]["bias"]).max()
            )
    return emit(out)


if __name__ == "__main__":
    main()
