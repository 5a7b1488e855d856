"""The full-strip benchmark of issue 6: jaxgeo's two-level adjustment against scipy and Ceres.

A simulated Carto-2S strip (``jaxgeo.simulate.carto2s_strip``: ``--scenes`` sub-scenes, GCPs in
every fourth one, ``--ties`` formed ties per adjacent pair) is adjusted by
``jaxgeo.strip.adjust_strip`` (level 1: bundle adjustment of all sub-scenes, affine bias each;
level 2: the universal correction). The *identical* level-1 problem (:func:`problem_dict`: the
same RPCs, observations, weights, starting point and unknowns) is then solved by the peers of
``benchmarks/peers/strip.py`` in the same run:

- ``scipy``: ``scipy.optimize.least_squares`` (trf, LSMR) with a finite-difference Jacobian
  grouped by the exact ``jac_sparsity`` (the issue's method), central differences and tight
  LSMR solves: the finite-difference set-up that reaches jaxgeo's solution to 1e-6 px;
  ``scipy-2point``: scipy's usual forward differences and default LSMR (stops short);
  ``scipy-analytic``: the analytic sparse Jacobian;
- ``ceres``: pyceres (Ceres, Levenberg-Marquardt, DENSE_SCHUR on the points), Python cost
  functions with analytic Jacobians.

Timings: ``jaxgeo_s`` is the best wall time of ``--repeat`` compiled two-level calls (level 1
*and* level 2) after compilation; the peers' times are the best of ``--peer-repeat`` solves of
level 1 only, problem set-up included (Ceres' own solver time is reported beside it).
Agreement: every image observation projected with a peer's solution and with jaxgeo's, the
largest difference in px.

Memory (``--memory-scenes``): for each strip size, XLA's memory analysis of the compiled
two-level call (arguments, outputs, temporaries: on CPU the temporaries are one preallocated
buffer, i.e. the call's peak working memory) against the number of tie points. These strips
have shorter sub-scenes (``--memory-scene-rows``; same array sizes) so that 320 of them stay
within what the simulator handles.

    python -m benchmarks.speed.strip [--scenes 80] [--ties 50] [--seed 0] [--peers scipy ceres]
                                     [--memory-scenes 20 80 320]

prints one JSON object on stdout (the machine last: :func:`benchmarks.harness.emit`; progress
on stderr).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

# threaded OpenBLAS (under jax's LAPACK calls) spin-waits on a busy machine: see adjust.py
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from benchmarks.harness import emit  # noqa: E402
from benchmarks.peers import strip as sp  # noqa: E402

PEERS = ("scipy", "scipy-2point", "scipy-analytic", "ceres")
LSMR_TOL = 1e-12
"""LSMR ``atol = btol`` of the scipy peers (scipy's default 1e-6 inner solves do not converge
on this ill-conditioned problem: the biases of scenes without GCPs are weakly determined)."""
CERES_TOL = 1e-12
"""Ceres' function / gradient / parameter tolerance (1e-14: ~2x the time, ~4e-9 px closer)."""


def _log(*args) -> None:
    print(*args, file=sys.stderr, flush=True)


def _only_group(res):
    prob = res.setup.problem
    (group,) = prob.groups
    if any(ob.group != 0 or ob.slot != 0 for ob in prob.images):
        raise ValueError("problem_dict: expected one group of single-image blocks")
    if res.config.solver.loss != "l2" or prob.prior_weight[0].shape[1]:
        raise ValueError("problem_dict: the peers have no robust loss and no bias priors")
    return group


def _status(sol) -> str:
    """The level-1 solve's outcome in words (``converged``, ``singular normal equations``...)."""
    from jaxgeo.lsq.internal import describe

    return describe(sol.result)[1]


def problem_dict(res) -> dict:
    """The level-1 problem of a :class:`jaxgeo.strip.StripResult` as the peers' problem dict.

    Scenes in jaxgeo's block order (``res.setup.image_index[name][1]``, kept as ``names``),
    points in ``res.setup.point_ids`` order starting at jaxgeo's initial points, the image
    observations and weights of ``res.setup.problem`` (``sigma = 1 / weight``) and its ground
    observations (``inf`` sigma on unobserved axes; observations without any observed axis are
    dropped). Ground residuals are linearised at each observed point (``gcp_scale``), the
    first-order equivalent of jaxgeo's exact ENU about the observed point. The peers' cost
    ``0.5 * sum(r**2)`` is half jaxgeo's ``Solution.cost`` (a plain sum of squares).
    """
    setup = res.setup
    prob = setup.problem
    group = _only_group(res)
    blocks = group.blocks(group.theta0)  # stacked Biased(RPC, AffineBias), one row per block
    rpc, bias = blocks.model, blocks.bias
    n = group.theta0.shape[0]
    names = sorted(setup.image_index, key=lambda k: setup.image_index[k][1])
    assert [setup.image_index[k][1] for k in names] == list(range(n))
    obs_scene = np.concatenate([np.asarray(ob.block) for ob in prob.images])
    obs_point = np.concatenate([np.asarray(ob.point) for ob in prob.images])
    obs_xy = np.concatenate([np.asarray(ob.xy) for ob in prob.images])
    obs_weight = np.concatenate([np.asarray(ob.weight) for ob in prob.images])
    weight = np.asarray(prob.ground.weight, dtype=float)
    keep = (weight > 0).any(axis=1)
    sigma = np.full(weight.shape, np.inf)
    np.divide(1.0, weight, out=sigma, where=weight > 0)
    lonlath = np.asarray(prob.ground.lonlath, dtype=float)[keep]
    points0 = np.asarray(prob.origin, dtype=float)
    out = {
        "num": np.asarray(rpc.num, dtype=float),
        "den": np.asarray(rpc.den, dtype=float),
        "ground_offset": np.asarray(rpc.ground_offset, dtype=float),
        "ground_scale": np.asarray(rpc.ground_scale, dtype=float),
        "image_offset": np.asarray(rpc.image_offset, dtype=float),
        "image_scale": np.asarray(rpc.image_scale, dtype=float),
        "bias0": np.concatenate(
            [np.asarray(bias.shift_px).reshape(n, 2), np.asarray(bias.matrix).reshape(n, 4)], 1
        ),
        "points0": points0,
        "obs_scene": obs_scene.astype(np.int64),
        "obs_point": obs_point.astype(np.int64),
        "obs_xy": obs_xy.astype(float),
        "obs_sigma": 1.0 / obs_weight.astype(float),
        "gcp_point": np.asarray(prob.ground.point, dtype=np.int64)[keep],
        "gcp_lonlath": lonlath,
        "gcp_sigma_m": sigma[keep],
        "gcp_scale": np.stack([sp.enu_scale(g) for g in lonlath]).reshape(-1, 3),
        "origin": points0.mean(axis=0),
        "names": tuple(names),
    }
    return sp.validate(out)


def jaxgeo_solution(res) -> tuple[np.ndarray, np.ndarray]:
    """jaxgeo's level-1 ``(bias (S,6), points (N,3))`` in the order of :func:`problem_dict`."""
    _only_group(res)
    sol = res.solution.level1
    return np.asarray(sol.theta[0], dtype=float), np.asarray(sol.ground, dtype=float)


def jaxgeo_cost(res, bias, points) -> float:
    """jaxgeo's own cost (sum of squared weighted residuals, ``jaxgeo.lsq.residuals``) at any
    ``bias`` (S,6) and ``points`` (N,3): ``Solution.cost`` at its solution."""
    import jax.numpy as jnp

    from jaxgeo.lsq import residuals

    prob = res.setup.problem
    group = _only_group(res)
    s = res.config.solver
    z = (jnp.asarray(bias) - group.theta0,)
    u = (jnp.asarray(points) - prob.origin) * prob.metres_per_unit
    args = (prob, (jnp.ones_like(group.theta0),), s.loss, s.loss_scale)
    img, gnd, prior = residuals((z, u), args)
    return float(sum(jnp.sum(x**2) for x in (*img, gnd, *prior)))


def projection_gap_px(problem: dict, a: tuple, b: tuple) -> float:
    """Largest distance (px) between the projections of every image observation's point with
    solution ``a = (bias, points)`` and with solution ``b``."""
    scene, point = problem["obs_scene"], problem["obs_point"]
    pa = sp.project_biased(problem, scene, a[1][point], a[0])
    pb = sp.project_biased(problem, scene, b[1][point], b[0])
    return float(np.max(np.linalg.norm(pa - pb, axis=-1)))


def simulate(n_scenes: int, seed: int, **options):
    """A simulated Carto-2S strip (``jaxgeo.simulate.carto2s_strip`` with ``options``)."""
    from jaxgeo.simulate import Carto2SStripSettings, carto2s_strip
    from jaxgeo.strip import Strip

    t0 = time.perf_counter()
    strip = Strip.from_simulation(carto2s_strip(n_scenes, seed, Carto2SStripSettings(**options)))
    _log(f"simulated {n_scenes} sub-scenes in {time.perf_counter() - t0:.1f} s")
    return strip


def least_squares_solver():
    """The strip's solver with least squares and no snooping: the peers' objective (the
    default's robust loss and gross-error removal are what ``benchmarks/accuracy/strip_gross.py``
    measures)."""
    import dataclasses

    from jaxgeo.strip._config import STRIP_SOLVER

    return dataclasses.replace(STRIP_SOLVER, loss="l2", remove_blunders=False)


def run_jaxgeo(strip, ties: int, repeat: int):
    """``adjust_strip`` once (compilation), then the best of ``repeat`` compiled calls."""
    from jaxgeo.strip import StripConfig, TieConfig, adjust_strip
    from jaxgeo.strip._batch import time_two_level

    t0 = time.perf_counter()
    config = StripConfig(ties=TieConfig(per_pair=ties), solver=least_squares_solver())
    res = adjust_strip(strip, config)
    _log(f"jaxgeo: adjust_strip (compilation included) {time.perf_counter() - t0:.1f} s")
    best = time_two_level(res, repeat=repeat)
    _log(f"jaxgeo: two-level call {best:.3f} s")
    return res, best


def run_peer(problem: dict, peer: str, max_nfev: int, ceres_tol: float = CERES_TOL) -> dict:
    """One peer on ``problem``.

    ``scipy``: trf with ``jac_sparsity`` and central differences (``3-point``) and LSMR to
    ``LSMR_TOL``: the finite-difference configuration that reaches jaxgeo's solution to 1e-6 px
    (forward differences stop short, their truncation error shifts the stationary point: ~4e-6
    px at 80 sub-scenes with tight LSMR, 3.5e-4 px at ``max_nfev`` with the default LSMR).
    ``scipy-2point``: scipy's usual sparse usage, forward differences and default LSMR.
    ``scipy-analytic``: the analytic sparse Jacobian. ``ceres``: pyceres, DENSE_SCHUR.
    """
    if peer == "ceres":
        return sp.solve_ceres(
            problem, max_num_iterations=max_nfev, function_tolerance=ceres_tol,
            gradient_tolerance=ceres_tol, parameter_tolerance=ceres_tol,
        )  # fmt: skip
    if peer == "scipy":
        return sp.solve_scipy(problem, max_nfev=max_nfev, jac="3-point", lsmr_tol=LSMR_TOL)
    if peer == "scipy-2point":
        return sp.solve_scipy(problem, max_nfev=max_nfev, jac="2-point")
    if peer == "scipy-analytic":
        return sp.solve_scipy(problem, max_nfev=max_nfev, jac="analytic", lsmr_tol=LSMR_TOL)
    raise ValueError(f"unknown peer {peer!r}; expected one of {PEERS}")


def compare_peers(
    res,
    problem: dict,
    peers,
    max_nfev: int,
    jaxgeo_s: float,
    ceres_tol: float = CERES_TOL,
    repeat: int = 1,
) -> dict:
    """Run ``peers`` on ``problem`` (each ``repeat`` times, best wall time kept, as jaxgeo's);
    times, iterations, costs and agreement with jaxgeo."""
    mine = jaxgeo_solution(res)
    half = 0.5 * jaxgeo_cost(res, *mine)  # the peers' convention, at jaxgeo's solution
    out: dict = {}
    sols: dict = {}
    for peer in peers:
        key = peer.replace("-", "_")
        if peer == "ceres":
            try:
                import pyceres  # noqa: F401
            except ImportError as err:
                out["ceres_s"] = None
                out["ceres_skipped"] = f"pyceres not importable: {err}"
                continue
        _log(f"{peer}: solving ...")
        times = []
        for _ in range(repeat):
            r = run_peer(problem, peer, max_nfev, ceres_tol)
            times.append(r["time_s"])
            _log(f"{peer}: {r['time_s']:.2f} s, status {r['status']}")
        r["time_s"] = min(times)
        out[f"{key}_s"] = r["time_s"]
        out[f"{key}_runs_s"] = times
        out[f"{key}_over_jaxgeo"] = r["time_s"] / jaxgeo_s
        for k, v in r.items():
            if k not in ("bias", "points", "time_s"):
                out[f"{key}_{k}"] = v
        out[f"{key}_cost_rel_to_jaxgeo"] = (r["cost"] - half) / half
        out[f"{key}_vs_jaxgeo_px_max"] = projection_gap_px(problem, (r["bias"], r["points"]), mine)
        # jaxgeo's own (exact-ENU) cost at the peer's solution, relative to jaxgeo's solution
        theirs = 0.5 * jaxgeo_cost(res, r["bias"], r["points"])
        out[f"jaxgeo_cost_at_{key}_rel"] = (theirs - half) / half
        sols[key] = (r["bias"], r["points"])
    keys = list(sols)
    for i, a in enumerate(keys):  # peers against each other
        for b in keys[i + 1 :]:
            out[f"{b}_vs_{a}_px_max"] = projection_gap_px(problem, sols[b], sols[a])
    return out


def check_costs(res, problem: dict) -> dict:
    """The peers' cost against jaxgeo's (``0.5 *`` its sum of squares, recomputed at the same
    point) at the initial point and at jaxgeo's solution; and jaxgeo's reported
    ``Solution.cost`` against its recomputation."""
    mine = jaxgeo_solution(res)
    start = (problem["bias0"], problem["points0"])
    j_start, j_sol = (0.5 * jaxgeo_cost(res, *x) for x in (start, mine))
    p_start, p_sol = sp.cost(problem, *start), sp.cost(problem, *mine)
    reported = 0.5 * float(res.solution.level1.cost)
    return {
        "initial_cost": p_start,
        "jaxgeo_cost": reported,
        "cost_rel_diff_initial": (p_start - j_start) / j_start,
        "cost_rel_diff_solution": (p_sol - j_sol) / j_sol,
        "jaxgeo_reported_cost_rel": (reported - j_sol) / j_sol,
    }


def memory_point(res, jaxgeo_s: float | None = None) -> dict:
    """XLA's memory analysis of the compiled two-level call of ``res`` (bytes)."""
    from jaxgeo.strip import _solve as solve

    c = res.config
    degree = solve.degree_index(c.level2.degree)  # what time_two_level passes
    args = (res.setup.problem, res.data, degree, c.solver)
    t0 = time.perf_counter()
    stats = solve.two_level_jit.lower(*args).compile().compiled.memory_analysis()
    compile_s = time.perf_counter() - t0
    n_scenes = len(res.strip.names)
    ties = len(res.inputs.tie_ids)
    peak = (
        stats.argument_size_in_bytes + stats.output_size_in_bytes
        + stats.temp_size_in_bytes - stats.alias_size_in_bytes
    )  # fmt: skip
    return {
        "scenes": n_scenes,
        "ties": ties,
        "tie_observations": int(len(res.inputs.ties.point)),
        "unknowns": int(res.setup.problem.n_unknowns),
        "argument_bytes": int(stats.argument_size_in_bytes),
        "output_bytes": int(stats.output_size_in_bytes),
        "temp_bytes": int(stats.temp_size_in_bytes),
        "peak_bytes": int(peak),
        "peak_bytes_per_tie": peak / ties,
        "temp_bytes_per_tie": stats.temp_size_in_bytes / ties,
        "dense_camera_system_bytes": 8 * (6 * n_scenes) ** 2,
        "compile_s": compile_s,
        "jaxgeo_s": jaxgeo_s,
        "jaxgeo_steps": int(res.solution.level1.num_steps),
        "jaxgeo_status": _status(res.solution.level1),
    }


def memory_scaling(points: list[dict]) -> dict:
    """Growth between the smallest and the largest size (``*_growth_over_linear``: 1.0 when
    memory grows like the number of ties), and a least-squares split of the temporaries into
    ``bytes_per_tie * ties + dense_copies * 8 (6 S)^2`` (the dense reduced camera system, which
    grows with the square of the number of sub-scenes: about 0 when the banded solve is used),
    and ``time_per_step_growth_over_linear``: the growth of the time of one solver step (two-level
    call over level-1 steps) over that of the ties, 1.0 when linear."""
    a, b = points[0], points[-1]
    ratio = b["ties"] / a["ties"]
    per_step = [p["jaxgeo_s"] / p["jaxgeo_steps"] for p in (a, b)]
    out = {
        "ties_ratio": ratio,
        "time_per_step_s": [p["jaxgeo_s"] / p["jaxgeo_steps"] for p in points],
        "time_per_step_growth_over_linear": per_step[1] / per_step[0] / ratio,
        "peak_ratio": b["peak_bytes"] / a["peak_bytes"],
        "temp_ratio": b["temp_bytes"] / a["temp_bytes"],
        "peak_growth_over_linear": b["peak_bytes"] / a["peak_bytes"] / ratio,
        "temp_growth_over_linear": b["temp_bytes"] / a["temp_bytes"] / ratio,
        "dense_camera_system_share_of_peak_largest": b["dense_camera_system_bytes"]
        / b["peak_bytes"],
    }
    if len(points) >= 3:
        design = np.array([[p["ties"], p["dense_camera_system_bytes"]] for p in points], float)
        temp = np.array([p["temp_bytes"] for p in points], float)
        coef, *_ = np.linalg.lstsq(design, temp, rcond=None)
        fit = design @ coef
        out["temp_fit_bytes_per_tie"] = float(coef[0])
        out["temp_fit_dense_copies"] = float(coef[1])
        out["temp_fit_max_rel_error"] = float(np.max(np.abs(fit - temp) / temp))
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=80)
    parser.add_argument("--ties", type=int, default=50, help="tie points per adjacent pair")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--peers", nargs="*", default=list(PEERS), choices=PEERS)
    parser.add_argument("--max-nfev", type=int, default=200, help="peers' iteration limit")
    parser.add_argument("--ceres-tol", type=float, default=CERES_TOL)
    parser.add_argument("--repeat", type=int, default=5, help="timed jaxgeo calls (best)")
    parser.add_argument("--peer-repeat", type=int, default=3, help="runs per peer (best)")
    parser.add_argument("--memory-scenes", type=int, nargs="*", default=[20, 80, 320])
    parser.add_argument(
        "--memory-scene-rows", type=int, default=12000,
        help="sub-scene rows of the memory strips (the simulator's default is 48000, but 320 "
        "such sub-scenes make a ~9400 km pass where the first scenes' GCPs are no longer "
        "measured and level 1 is singular; array sizes, hence memory, do not depend on it)",
    )  # fmt: skip
    args = parser.parse_args(argv)

    strip = simulate(args.scenes, args.seed)
    res, jaxgeo_s = run_jaxgeo(strip, args.ties, args.repeat)
    problem = problem_dict(res)
    rep = res.report.strip
    out: dict = {
        "scenes": len(strip.names),
        "unknowns": int(res.setup.problem.n_unknowns),
        "jaxgeo_s": jaxgeo_s,
        "scipy_s": None,
        "ceres_s": None,
        "relative_rms_m": rep["tie_gap_m"]["level1"]["rms"],
        "absolute_rms_m": rep["check_rms_m"]["level2"]["plan"],
        "ties_per_pair": args.ties,
        "tie_points": len(res.inputs.tie_ids),
        "image_observations": int(len(problem["obs_scene"])),
        "gcp_scenes": rep["gcp_scenes"],
        "n_gcp": rep["n_gcp"],
        "n_check": rep["n_check"],
        "direct_relative_rms_m": rep["tie_gap_m"]["direct"]["rms"],
        "direct_absolute_rms_m": rep["check_rms_m"]["direct"]["plan"],
        "level1_absolute_rms_m": rep["check_rms_m"]["level1"]["plan"],
        "level2_relative_rms_m": rep["tie_gap_m"]["level2"]["rms"],
        "jaxgeo_setup_s": res.timings_s["setup"],
        "jaxgeo_first_call_s": res.timings_s["first_call"],
        "jaxgeo_steps": int(res.solution.level1.num_steps),
        "jaxgeo_status": _status(res.solution.level1),
        "jaxgeo_s0": rep["s0"],
    }
    out["peer_settings"] = {
        "scipy": f"trf, jac_sparsity, 3-point, x_scale jac, LSMR tol {LSMR_TOL:g}, "
        "ftol = xtol = gtol = 1e-12",
        "scipy_2point": "trf, jac_sparsity, 2-point, x_scale jac, default LSMR, "
        "ftol = xtol = gtol = 1e-12",
        "scipy_analytic": f"trf, analytic sparse Jacobian, LSMR tol {LSMR_TOL:g}",
        "ceres": f"LM, DENSE_SCHUR, Python cost functions, tolerances {args.ceres_tol:g}",
        "max_nfev": args.max_nfev,
        "timing": f"best wall time of {args.peer_repeat} runs per peer (set-up included), "
        f"of {args.repeat} compiled two-level calls for jaxgeo",
    }
    out.update(check_costs(res, problem))
    _log(f"cost check: {out['cost_rel_diff_initial']:.2e} (initial), "
         f"{out['cost_rel_diff_solution']:.2e} (jaxgeo's solution)")  # fmt: skip
    out.update(
        compare_peers(
            res, problem, args.peers, args.max_nfev, jaxgeo_s, args.ceres_tol, args.peer_repeat
        )
    )
    if args.memory_scenes:
        mem = []
        del res, problem  # free the main strip's arrays
        for n in sorted(set(args.memory_scenes)):
            sim = simulate(n, args.seed, scene_rows=args.memory_scene_rows)
            r, t = run_jaxgeo(sim, args.ties, 2)
            mem.append(memory_point(r, t) | {"scene_rows": args.memory_scene_rows})
            del sim, r
            _log(f"memory: {mem[-1]}")
        out["memory"] = mem
        if len(mem) > 1:
            out["memory_scaling"] = memory_scaling(mem)
    return emit(out, default=str)


if __name__ == "__main__":
    main()
