"""The Ceres peer of the strip benchmark: pyceres with Python cost functions and a Schur solver.

On the problem dict of :mod:`benchmarks.peers.strip` (same model, residuals and cost; see its
docstring). Needs
``pyceres`` (the ``bench`` extra).
"""

from __future__ import annotations

import time

import numpy as np
import pyceres

from benchmarks.peers.strip import ground_scale_m, validate


class ImageCost(pyceres.CostFunction):
    """One image observation; parameter blocks: bias of its scene (6), its point (3)."""

    def __init__(self, problem: dict, scene: int, obs: int):
        pyceres.CostFunction.__init__(self)
        self.set_num_residuals(2)
        self.set_parameter_block_sizes([6, 3])
        self.coeffs = np.concatenate([problem["num"][scene], problem["den"][scene]])  # (4,20)
        self.go = problem["ground_offset"][scene].tolist()
        self.gs = problem["ground_scale"][scene].tolist()
        self.io = problem["image_offset"][scene].tolist()
        self.iscale = problem["image_scale"][scene].tolist()
        self.x_obs, self.y_obs = problem["obs_xy"][obs].tolist()
        self.w = 1.0 / float(problem["obs_sigma"][obs])

    def Evaluate(self, parameters, residuals, jacobians):
        b0, a0, m00, m01, m10, m11 = parameters[0].tolist()
        lon_d, lat_d, h_m = parameters[1].tolist()
        (go0, go1, go2), (gs0, gs1, gs2) = self.go, self.gs
        lon, lat, h = (lon_d - go0) / gs0, (lat_d - go1) / gs1, (h_m - go2) / gs2
        ll, pp, hh, lp, lh, ph = lon * lon, lat * lat, h * h, lon * lat, lon * h, lat * h
        t = [1.0, lon, lat, h, lp, lh, ph, ll, pp, hh,
             lp * h, ll * lon, lon * pp, lon * hh, ll * lat, pp * lat, lat * hh, ll * h,
             pp * h, hh * h]  # fmt: skip
        want_jac = jacobians is not None
        if want_jac:
            mono = np.array(
                [t,
                 [0.0, 1.0, 0.0, 0.0, lat, h, 0.0, 2 * lon, 0.0, 0.0,
                  ph, 3 * ll, pp, hh, 2 * lp, 0.0, 0.0, 2 * lh, 0.0, 0.0],
                 [0.0, 0.0, 1.0, 0.0, lon, 0.0, h, 0.0, 2 * lat, 0.0,
                  lh, 0.0, 2 * lp, 0.0, ll, 3 * pp, hh, 0.0, 2 * ph, 0.0],
                 [0.0, 0.0, 0.0, 1.0, 0.0, lon, lat, 0.0, 0.0, 2 * h,
                  lp, 0.0, 0.0, 2 * lh, 0.0, 0.0, 2 * ph, ll, pp, 3 * hh]]
            )  # fmt: skip
            v = (self.coeffs @ mono.T).tolist()  # rows: num x, num y, den x, den y
        else:
            v = [[c] for c in (self.coeffs @ np.array(t)).tolist()]
        nx, ny, dx, dy = v
        rx, ry = nx[0] / dx[0], ny[0] / dy[0]
        qx = self.io[0] + self.iscale[0] * rx
        qy = self.io[1] + self.iscale[1] * ry
        # (I + M) p = q - a0
        e00, e01, e10, e11 = 1.0 + m00, m01, m10, 1.0 + m11
        det = e00 * e11 - e01 * e10
        i00, i01, i10, i11 = e11 / det, -e01 / det, -e10 / det, e00 / det
        ux, uy = qx - b0, qy - a0
        px, py = i00 * ux + i01 * uy, i10 * ux + i11 * uy
        w = self.w
        residuals[0] = (px - self.x_obs) * w
        residuals[1] = (py - self.y_obs) * w
        if not want_jac:
            return True
        if jacobians[0] is not None:
            c00, c10, c01, c11 = -i00 * w, -i10 * w, -i01 * w, -i11 * w
            jacobians[0][:] = [
                c00, c01, c00 * px, c00 * py, c01 * px, c01 * py,
                c10, c11, c10 * px, c10 * py, c11 * px, c11 * py,
            ]  # fmt: skip
        if jacobians[1] is not None:
            sx, sy = self.iscale[0] / dx[0], self.iscale[1] / dy[0]
            dqx = [sx * (nx[k] - rx * dx[k]) / g for k, g in ((1, gs0), (2, gs1), (3, gs2))]
            dqy = [sy * (ny[k] - ry * dy[k]) / g for k, g in ((1, gs0), (2, gs1), (3, gs2))]
            jacobians[1][:] = [w * (i00 * a + i01 * b) for a, b in zip(dqx, dqy, strict=True)] + [
                w * (i10 * a + i11 * b) for a, b in zip(dqx, dqy, strict=True)
            ]
        return True


class GroundCost(pyceres.CostFunction):
    """One ground observation (its finite axes only); parameter block: its point (3)."""

    def __init__(self, observed: np.ndarray, weight: np.ndarray, axes: np.ndarray):
        pyceres.CostFunction.__init__(self)
        self.set_num_residuals(len(axes))
        self.set_parameter_block_sizes([3])
        self.axes, self.observed, self.weight = axes, observed[axes], weight
        jac = np.zeros((len(axes), 3))
        jac[np.arange(len(axes)), axes] = weight
        self.jac = jac.ravel()

    def Evaluate(self, parameters, residuals, jacobians):
        residuals[:] = (parameters[0][self.axes] - self.observed) * self.weight
        if jacobians is not None and jacobians[0] is not None:
            jacobians[0][:] = self.jac
        return True


def solve_ceres(
    problem: dict,
    max_num_iterations: int = 100,
    function_tolerance: float = 1e-12,
    gradient_tolerance: float = 1e-12,
    parameter_tolerance: float = 1e-12,
    linear_solver: str = "DENSE_SCHUR",
    num_threads: int = 1,
    verbose: bool = False,
) -> dict:
    """Ceres (pyceres) Levenberg-Marquardt with a Schur solver and Python cost functions.

    One residual block per image observation (blocks: its scene's bias, its point) and one per
    ground observation, with analytic Jacobians in Python. pyceres does not expose
    ``linear_solver_ordering``; Ceres' automatic ordering for Schur solvers eliminates a maximal
    independent set, here the point blocks (checked: ``eliminated_blocks`` in the output).
    Returns ``bias``, ``points``, ``cost``, ``nfev``, ``iterations``, ``time_s`` (wall, problem
    building included), ``cpu_s``, Ceres' own ``ceres_total_s``, ``ceres_linear_solver_s``,
    ``ceres_residual_s``, ``ceres_jacobian_s``, ``status`` (termination type) and ``message``.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    problem = validate(problem)
    bias = [np.array(b, dtype=float) for b in problem["bias0"]]
    points = [np.array(p, dtype=float) for p in problem["points0"]]
    ceres_problem = pyceres.Problem()
    for b in bias:
        ceres_problem.add_parameter_block(b, 6)
    for p in points:
        ceres_problem.add_parameter_block(p, 3)
    costs = []  # keep the Python objects alive for the whole solve
    pairs = zip(problem["obs_scene"].tolist(), problem["obs_point"].tolist(), strict=True)
    for m, (s, i) in enumerate(pairs):
        costs.append(ImageCost(problem, s, m))
        ceres_problem.add_residual_block(costs[-1], None, [bias[s], points[i]])
    scale = ground_scale_m(problem)  # enu_scale(origin), or the problem's gcp_scale
    for c, i in enumerate(problem["gcp_point"].tolist()):
        axes = np.flatnonzero(np.isfinite(problem["gcp_sigma_m"][c]))
        if axes.size:
            weight = scale[c, axes] / problem["gcp_sigma_m"][c, axes]
            costs.append(GroundCost(problem["gcp_lonlath"][c], weight, axes))
            ceres_problem.add_residual_block(costs[-1], None, [points[i]])
    options = pyceres.SolverOptions()
    options.linear_solver_type = getattr(pyceres.LinearSolverType, linear_solver)
    options.max_num_iterations = max_num_iterations
    options.function_tolerance = function_tolerance
    options.gradient_tolerance = gradient_tolerance
    options.parameter_tolerance = parameter_tolerance
    options.num_threads = num_threads
    options.minimizer_progress_to_stdout = verbose
    summary = pyceres.SolverSummary()
    pyceres.solve(options, ceres_problem, summary)
    elapsed = time.perf_counter() - t0
    report = summary.FullReport()
    return {
        "bias": np.stack(bias),
        "points": np.stack(points),
        "cost": float(summary.final_cost),
        "initial_cost": float(summary.initial_cost),
        "nfev": int(summary.num_residual_evaluations),
        "iterations": int(summary.num_successful_steps + summary.num_unsuccessful_steps),
        "time_s": elapsed,
        "cpu_s": time.process_time() - c0,
        "ceres_total_s": float(summary.total_time_in_seconds),
        "ceres_linear_solver_s": float(summary.linear_solver_time_in_seconds),
        "ceres_residual_s": float(summary.residual_evaluation_time_in_seconds),
        "ceres_jacobian_s": float(summary.jacobian_evaluation_time_in_seconds),
        "eliminated_blocks": _eliminated_blocks(report),
        "linear_solver": str(summary.linear_solver_type_used).split(".")[-1],
        "status": str(summary.termination_type).split(".")[-1],
        "message": str(summary.message),
    }


def _eliminated_blocks(report: str) -> int | None:
    """The size of the first elimination group in Ceres' full report ("Linear solver ordering")."""
    for line in report.splitlines():
        if line.strip().startswith("Linear solver ordering"):
            used = line.split()[-1]  # "given  used": AUTOMATIC  n_eliminated,n_rest
            try:
                return int(used.split(",")[0])
            except ValueError:
                return None
    return None
