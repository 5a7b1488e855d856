"""Peer solvers for the full-strip bundle adjustment: scipy and Ceres on one numpy problem.

The problem is a dict of numpy arrays (float64 / int), the same one jaxgeo's engine is given:

==================  =========  =====================================================================
key                 shape      meaning
==================  =========  =====================================================================
num, den            (S,2,20)   RPC numerators / denominators, row 0 sample (x), row 1 line (y),
                               RPC00B term order (jaxgeo.models.RPC stacked)
ground_offset/scale (S,3)      RPC normalisation of (lon_deg, lat_deg, h_m)
image_offset/scale  (S,2)      RPC normalisation of (x, y) px
bias0               (S,6)      initial affine bias [B0, A0, B2, B1, A2, A1] (jaxgeo.models._bias)
points0             (N,3)      initial ground points (lon_deg, lat_deg, h_m)
obs_scene/obs_point (M,)       scene / point index of each image observation
obs_xy, obs_sigma   (M,2),(M,) measured image point (x, y) px and its sigma px
gcp_point           (C,)       point index of each ground observation (GCP or height prior)
gcp_lonlath         (C,3)      observed (lon_deg, lat_deg, h_m)
gcp_sigma_m         (C,3)      sigma east / north / up in metres; ``inf`` drops that axis
origin              (3,)       (lon_deg, lat_deg, h_m) where ENU metres are linearised
gcp_scale           (C,3)      optional: metres per unit of (lon_deg, lat_deg, h_m) for each ground
                               observation (e.g. ``enu_scale`` of its ``gcp_lonlath``), used in
                               place of ``enu_scale(origin)`` when given
==================  =========  =====================================================================

Model: the biased projection of point ``g`` in scene ``s`` is
``(I + M)^-1 (rpc_s(g) - a0)`` with ``a0 = (B0, A0)`` and ``M = [[B2, B1], [A2, A1]]``, i.e.
``jaxgeo.Biased(rpc, AffineBias(shift_px=(B0, A0), matrix=M)).project``. Residuals, all whitened:
``(project - obs_xy) / obs_sigma`` (2 per image observation, listed first), then
``enu_scale(origin) * (point - gcp_lonlath) / gcp_sigma_m`` for every finite sigma (``gcp_scale``
in place of ``enu_scale(origin)`` when given: ENU linearised at each observed point, which over a
long strip is what jaxgeo's exact ENU about the observed point amounts to). The cost is
``0.5 * sum(residuals**2)``; the unknowns are ``bias`` (S,6) and ``points`` (N,3), stacked as
``x = [bias.ravel(), points.ravel()]``.

``python -m benchmarks.speed.strip_peers`` times the peers alone on a synthetic problem
(:mod:`benchmarks.peers.strip_synth`); ``python -m benchmarks.speed.strip`` against jaxgeo on
jaxgeo's own problem. The Ceres peer lives in :mod:`benchmarks.peers.strip_ceres`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.sparse

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

PROBLEM_SHAPES = {
    "num": ("S", 2, 20),
    "den": ("S", 2, 20),
    "ground_offset": ("S", 3),
    "ground_scale": ("S", 3),
    "image_offset": ("S", 2),
    "image_scale": ("S", 2),
    "bias0": ("S", 6),
    "points0": ("N", 3),
    "obs_scene": ("M",),
    "obs_point": ("M",),
    "obs_xy": ("M", 2),
    "obs_sigma": ("M",),
    "gcp_point": ("C",),
    "gcp_lonlath": ("C", 3),
    "gcp_sigma_m": ("C", 3),
    "origin": (3,),
}
"""Every key of a strip problem and its shape (letters: sizes shared between keys)."""
_INT_KEYS = ("obs_scene", "obs_point", "gcp_point")


def validate(problem: dict) -> dict:
    """Check keys, shapes, indices and sigmas; return a copy with float64 / int64 arrays.

    Raises ``ValueError`` naming the key (and the first observation) at fault. Extra keys
    (e.g. the synthetic truth ``bias_true``) are kept and ignored by the solvers.
    """
    out = dict(problem)
    sizes: dict[str, int] = {}
    for key, shape in PROBLEM_SHAPES.items():
        if key not in problem:
            raise ValueError(f"strip problem: missing key {key!r}")
        arr = np.asarray(problem[key], dtype=np.int64 if key in _INT_KEYS else np.float64)
        if arr.ndim != len(shape):
            raise ValueError(f"strip problem: {key!r} must have shape {shape}, got {arr.shape}")
        for dim, want in zip(arr.shape, shape, strict=True):
            if isinstance(want, str):
                if sizes.setdefault(want, dim) != dim:
                    raise ValueError(
                        f"strip problem: {key!r} has {want}={dim}, other keys have {sizes[want]}"
                    )
            elif dim != want:
                raise ValueError(f"strip problem: {key!r} must have shape {shape}, got {arr.shape}")
        out[key] = arr
    for key, size in (("obs_scene", "S"), ("obs_point", "N"), ("gcp_point", "N")):
        bad = np.flatnonzero((out[key] < 0) | (out[key] >= sizes[size]))
        if bad.size:
            raise ValueError(
                f"strip problem: {key}[{bad[0]}] = {out[key][bad[0]]} is outside "
                f"0..{sizes[size] - 1}"
            )
    for key in ("obs_sigma", "gcp_sigma_m"):
        bad = np.flatnonzero(~(out[key] > 0).reshape(len(out[key]), -1).all(axis=1))
        if bad.size:
            raise ValueError(f"strip problem: {key}[{bad[0]}] is not > 0")
    if "gcp_scale" in problem:
        scale = np.asarray(problem["gcp_scale"], dtype=np.float64)
        if scale.shape != out["gcp_lonlath"].shape:
            raise ValueError(
                f"strip problem: 'gcp_scale' must have shape {out['gcp_lonlath'].shape} (as "
                f"'gcp_lonlath'), got {scale.shape}"
            )
        bad = np.flatnonzero(~((scale > 0) | ~np.isfinite(out["gcp_sigma_m"])).all(axis=1))
        if bad.size:
            raise ValueError(f"strip problem: gcp_scale[{bad[0]}] is not > 0 on a used axis")
        out["gcp_scale"] = scale
    bad = np.flatnonzero(~np.isfinite(out["obs_sigma"]))
    if bad.size:
        raise ValueError(f"strip problem: obs_sigma[{bad[0]}] is not finite")
    used = np.isfinite(out["gcp_sigma_m"])
    for key, ok in (
        ("gcp_lonlath", np.isfinite(out["gcp_lonlath"]) | ~used),
        ("obs_xy", np.isfinite(out["obs_xy"])),
        ("points0", np.isfinite(out["points0"])),
        ("bias0", np.isfinite(out["bias0"])),
    ):
        bad = np.flatnonzero(~ok.all(axis=1))
        if bad.size:
            raise ValueError(f"strip problem: {key}[{bad[0]}] holds a non-finite value")
    return out


def enu_scale(origin) -> np.ndarray:
    """Metres per (deg lon, deg lat, m h) at ``origin`` = (lon_deg, lat_deg, h_m), WGS84.

    The exact derivative of local ENU coordinates with respect to geodetic coordinates at the
    origin: ``east = (N + h) cos(lat) dlon``, ``north = (M + h) dlat`` (radians),
    ``up = dh``, with ``N = a / sqrt(1 - e2 sin^2 lat)`` the prime-vertical and
    ``M = a (1 - e2) / (1 - e2 sin^2 lat)^1.5`` the meridian radius of curvature. Ground
    observation residuals use this one linearisation for the whole problem.
    """
    lat = math.radians(float(origin[1]))
    h = float(origin[2])
    w2 = 1.0 - WGS84_E2 * math.sin(lat) ** 2
    prime_vertical = WGS84_A_M / math.sqrt(w2)
    meridian = WGS84_A_M * (1.0 - WGS84_E2) / w2**1.5
    deg = math.pi / 180.0
    return np.array([(prime_vertical + h) * math.cos(lat) * deg, (meridian + h) * deg, 1.0])


def ground_scale_m(problem: dict) -> np.ndarray:
    """(C,3) metres per unit of (lon_deg, lat_deg, h_m) of every ground observation: the
    problem's ``gcp_scale`` if given, else ``enu_scale(origin)`` for all."""
    if "gcp_scale" in problem:
        return np.asarray(problem["gcp_scale"], dtype=float)
    return np.tile(enu_scale(problem["origin"]), (len(problem["gcp_point"]), 1))


def _monomials(n: np.ndarray, jacobian: bool):
    """RPC00B monomials of normalised (L, P, H) ``n`` (m,3) -> (m,20) and (m,20,3) gradients."""
    lon, lat, h = n[:, 0], n[:, 1], n[:, 2]
    one, zero = np.ones_like(lon), np.zeros_like(lon)
    ll, pp, hh, lp, lh, ph = lon * lon, lat * lat, h * h, lon * lat, lon * h, lat * h
    t = np.stack(
        [one, lon, lat, h, lp, lh, ph, ll, pp, hh, lp * h, ll * lon, lon * pp, lon * hh,
         ll * lat, pp * lat, lat * hh, ll * h, pp * h, hh * h],
        axis=-1,
    )  # fmt: skip
    if not jacobian:
        return t, None
    d_lon = [zero, one, zero, zero, lat, h, zero, 2 * lon, zero, zero,
             ph, 3 * ll, pp, hh, 2 * lp, zero, zero, 2 * lh, zero, zero]  # fmt: skip
    d_lat = [zero, zero, one, zero, lon, zero, h, zero, 2 * lat, zero,
             lh, zero, 2 * lp, zero, ll, 3 * pp, hh, zero, 2 * ph, zero]  # fmt: skip
    d_h = [zero, zero, zero, one, zero, lon, lat, zero, zero, 2 * h,
           lp, zero, zero, 2 * lh, zero, zero, 2 * ph, ll, pp, 3 * hh]  # fmt: skip
    dt = np.stack([np.stack(d_lon, -1), np.stack(d_lat, -1), np.stack(d_h, -1)], axis=-1)
    return t, dt


def _rpc(problem: dict, scene: np.ndarray, ground: np.ndarray, jacobian: bool):
    """RPC projection of ``ground`` (m,3) in ``scene`` (m,) -> (m,2) px and (m,2,3) px/unit."""
    gs = problem["ground_scale"][scene]
    t, dt = _monomials((ground - problem["ground_offset"][scene]) / gs, jacobian)
    num = np.einsum("mkt,mt->mk", problem["num"][scene], t)
    den = np.einsum("mkt,mt->mk", problem["den"][scene], t)
    ratio = num / den
    iscale = problem["image_scale"][scene]
    xy = problem["image_offset"][scene] + iscale * ratio
    if not jacobian:
        return xy, None
    d_num = np.einsum("mkt,mtd->mkd", problem["num"][scene], dt)
    d_den = np.einsum("mkt,mtd->mkd", problem["den"][scene], dt)
    d_ratio = (d_num - ratio[..., None] * d_den) / den[..., None]
    return xy, iscale[:, :, None] * d_ratio / gs[:, None, :]


def _biased(problem, scene, ground, bias, jacobian: bool):
    """Biased projection (m,2) and its Jacobians wrt the scene's bias (m,2,6) and ground (m,2,3)."""
    q, dq = _rpc(problem, scene, ground, jacobian)
    b = bias[scene]
    a00, a01, a10, a11 = 1.0 + b[:, 2], b[:, 3], b[:, 4], 1.0 + b[:, 5]
    det = a00 * a11 - a01 * a10
    inv = np.stack([np.stack([a11, -a01], -1), np.stack([-a10, a00], -1)], -2) / det[:, None, None]
    p = np.einsum("mij,mj->mi", inv, q - b[:, :2])
    if not jacobian:
        return p, None, None
    # (I + M) p = q - a0  =>  dp = (I + M)^-1 (dq - da0 - dM p)
    c0, c1 = -inv[:, :, 0], -inv[:, :, 1]
    p0, p1 = p[:, 0:1], p[:, 1:2]
    d_bias = np.stack([c0, c1, c0 * p0, c0 * p1, c1 * p0, c1 * p1], axis=-1)
    return p, d_bias, np.einsum("mij,mjd->mid", inv, dq)


def rpc_project(problem: dict, scene, lonlath, jacobian: bool = False):
    """Unbiased RPC projection: ``scene`` int or (...,), ``lonlath`` (...,3) -> (x, y) (...,2).

    With ``jacobian=True`` also returns d(x, y)/d(lon_deg, lat_deg, h_m), shape (...,2,3).
    """
    lonlath = np.asarray(lonlath, dtype=float)
    batch = lonlath.shape[:-1]
    scene = np.broadcast_to(np.asarray(scene, dtype=np.int64), batch).reshape(-1)
    xy, d = _rpc(problem, scene, lonlath.reshape(-1, 3), jacobian)
    xy = xy.reshape(*batch, 2)
    return (xy, d.reshape(*batch, 2, 3)) if jacobian else xy


def project_biased(problem: dict, scene, lonlath, bias) -> np.ndarray:
    """Biased projection ``(I + M)^-1 (rpc(lonlath) - a0)`` -> (x, y) px, shape (...,2).

    ``scene`` is an int or an index array broadcasting with ``lonlath`` (...,3); ``bias`` is the
    (S,6) array of all scenes ([B0, A0, B2, B1, A2, A1] each).
    """
    lonlath = np.asarray(lonlath, dtype=float)
    batch = lonlath.shape[:-1]
    scene = np.broadcast_to(np.asarray(scene, dtype=np.int64), batch).reshape(-1)
    bias = np.asarray(bias, dtype=float).reshape(-1, 6)
    p, _, _ = _biased(problem, scene, lonlath.reshape(-1, 3), bias, False)
    return p.reshape(*batch, 2)


@dataclass(frozen=True)
class Layout:
    """Fixed structure of a validated problem: sizes and the ground-residual rows."""

    n_scenes: int
    n_points: int
    n_obs: int
    gcp_rows: np.ndarray  # (G,) ground observation of each ground residual
    gcp_axes: np.ndarray  # (G,) axis 0/1/2 of each ground residual
    gcp_weight: np.ndarray  # (G,) enu_scale[axis] / sigma: residual per unit of the coordinate

    @classmethod
    def of(cls, problem: dict) -> Layout:
        finite = np.isfinite(problem["gcp_sigma_m"])
        rows, axes = np.nonzero(finite)
        weight = ground_scale_m(problem)[rows, axes] / problem["gcp_sigma_m"][rows, axes]
        return cls(
            n_scenes=len(problem["num"]),
            n_points=len(problem["points0"]),
            n_obs=len(problem["obs_scene"]),
            gcp_rows=rows,
            gcp_axes=axes,
            gcp_weight=weight,
        )

    @property
    def n_unknowns(self) -> int:
        return 6 * self.n_scenes + 3 * self.n_points

    @property
    def n_residuals(self) -> int:
        return 2 * self.n_obs + len(self.gcp_rows)

    def split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unknown vector -> (bias (S,6), points (N,3))."""
        return x[: 6 * self.n_scenes].reshape(-1, 6), x[6 * self.n_scenes :].reshape(-1, 3)


def _residuals(problem, layout: Layout, bias, points, jacobian: bool):
    scene, point = problem["obs_scene"], problem["obs_point"]
    p, d_bias, d_point = _biased(problem, scene, points[point], bias, jacobian)
    inv_sigma = 1.0 / problem["obs_sigma"]
    r_img = (p - problem["obs_xy"]) * inv_sigma[:, None]
    gp = problem["gcp_point"][layout.gcp_rows]
    r_gcp = (
        points[gp, layout.gcp_axes] - problem["gcp_lonlath"][layout.gcp_rows, layout.gcp_axes]
    ) * layout.gcp_weight
    r = np.concatenate([r_img.ravel(), r_gcp])
    if not jacobian:
        return r, None
    # (M, 2, 9) row-major: the CSR layout of _pattern (6 bias entries then 3 point entries)
    data = np.concatenate([d_bias, d_point], axis=-1) * inv_sigma[:, None, None]
    return r, data.ravel()


def _pattern(problem: dict, layout: Layout):
    """CSR indices of the exact Jacobian sparsity: 9 entries per image row, 1 per ground row."""
    s = 6 * layout.n_scenes
    scene, point = problem["obs_scene"], problem["obs_point"]
    cols_img = np.concatenate(
        [6 * scene[:, None] + np.arange(6), s + 3 * point[:, None] + np.arange(3)], axis=1
    )  # (M, 9)
    cols_img = np.repeat(cols_img[:, None, :], 2, axis=1).reshape(-1)
    cols_gcp = s + 3 * problem["gcp_point"][layout.gcp_rows] + layout.gcp_axes
    indices = np.concatenate([cols_img, cols_gcp])
    indptr = np.concatenate(
        [
            np.arange(0, 18 * layout.n_obs + 1, 9),
            18 * layout.n_obs + np.arange(1, len(cols_gcp) + 1),
        ]
    )
    return indices, indptr


def jac_sparsity(problem: dict) -> scipy.sparse.csr_matrix:
    """The exact 0/1 sparsity pattern of the Jacobian (rows: residuals, columns: unknowns)."""
    problem = validate(problem)
    layout = Layout.of(problem)
    indices, indptr = _pattern(problem, layout)
    shape = (layout.n_residuals, layout.n_unknowns)
    return scipy.sparse.csr_matrix((np.ones(len(indices)), indices, indptr), shape=shape)


def residuals(problem: dict, bias, points) -> np.ndarray:
    """All whitened residuals: 2 per image observation, then one per finite ground sigma."""
    problem = validate(problem)
    bias = np.asarray(bias, dtype=float)
    return _residuals(problem, Layout.of(problem), bias, np.asarray(points, dtype=float), False)[0]


def cost(problem: dict, bias, points) -> float:
    """``0.5 * sum(residuals**2)`` (the convention of scipy and Ceres)."""
    r = residuals(problem, bias, points)
    return 0.5 * float(r @ r)


def jacobian(problem: dict, bias, points) -> scipy.sparse.csr_matrix:
    """The analytic Jacobian of :func:`residuals` as a CSR matrix."""
    problem = validate(problem)
    layout = Layout.of(problem)
    return _Evaluator(problem, layout).jac(np.concatenate([np.ravel(bias), np.ravel(points)]))


class _Evaluator:
    """Residual / Jacobian callbacks on the stacked unknown vector, for scipy."""

    def __init__(self, problem: dict, layout: Layout):
        self.problem, self.layout = problem, layout
        self.indices, self.indptr = _pattern(problem, layout)
        self.shape = (layout.n_residuals, layout.n_unknowns)

    def fun(self, x):
        bias, points = self.layout.split(x)
        return _residuals(self.problem, self.layout, bias, points, False)[0]

    def jac(self, x):
        bias, points = self.layout.split(x)
        _, data_img = _residuals(self.problem, self.layout, bias, points, True)
        data = np.concatenate([data_img, self.layout.gcp_weight])
        return scipy.sparse.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


def solve_scipy(
    problem: dict,
    max_nfev: int | None = 200,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    gtol: float = 1e-12,
    jac: str = "2-point",
    lsmr_tol: float | None = None,
    verbose: int = 0,
) -> dict:
    """``scipy.optimize.least_squares`` (trf, LSMR, ``x_scale="jac"``) on the strip problem.

    ``jac="2-point"`` (default) is scipy's usual sparse usage: finite differences grouped by the
    exact ``jac_sparsity`` (``"3-point"``: central differences, twice the evaluations);
    ``jac="analytic"`` passes the analytic sparse Jacobian instead.
    ``lsmr_tol`` sets LSMR's ``atol = btol`` (scipy's default, 1e-6, when None): the default
    inner solves are too loose to converge to 1e-8 in cost on this ill-conditioned problem
    (the affine biases of scenes without GCPs are weakly determined); 1e-12 converges in a few
    iterations with the analytic Jacobian.
    Returns ``bias``, ``points``, ``cost``, ``nfev``, ``njev``, ``time_s`` (wall, set-up
    included), ``cpu_s`` (process CPU time: the machine is shared), ``status`` (scipy's code;
    0 = stopped at ``max_nfev``), ``message``.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    problem = validate(problem)
    layout = Layout.of(problem)
    ev = _Evaluator(problem, layout)
    x0 = np.concatenate([problem["bias0"].ravel(), problem["points0"].ravel()])
    if jac in ("2-point", "3-point"):
        kwargs = dict(jac=jac, jac_sparsity=scipy.sparse.csr_matrix(
            (np.ones(len(ev.indices)), ev.indices, ev.indptr), shape=ev.shape))  # fmt: skip
    elif jac == "analytic":
        kwargs = dict(jac=ev.jac)
    else:
        raise ValueError(
            f"solve_scipy: jac must be '2-point', '3-point' or 'analytic', got {jac!r}"
        )
    res = scipy.optimize.least_squares(
        ev.fun, x0, method="trf", x_scale="jac", tr_solver="lsmr", ftol=ftol, xtol=xtol,
        gtol=gtol, max_nfev=max_nfev, verbose=verbose,
        tr_options={} if lsmr_tol is None else {"atol": lsmr_tol, "btol": lsmr_tol}, **kwargs,
    )  # fmt: skip
    elapsed = time.perf_counter() - t0
    bias, points = layout.split(res.x)
    return {
        "bias": bias.copy(),
        "points": points.copy(),
        "cost": float(res.cost),
        "nfev": int(res.nfev),
        "njev": int(res.njev) if res.njev is not None else None,
        "time_s": elapsed,
        "cpu_s": time.process_time() - c0,
        "status": int(res.status),
        "message": str(res.message),
    }


def solve_ceres(problem: dict, **options) -> dict:
    """The Ceres peer (pyceres, Schur, Python cost functions): see :mod:`.strip_ceres`."""
    from benchmarks.peers.strip_ceres import solve_ceres as solve

    return solve(problem, **options)


def bias_effect_px(problem: dict, bias_a, bias_b) -> np.ndarray:
    """Per scene, the largest difference (px) of ``to_model = image + a0 + M image`` at the four
    image corners between two bias arrays (S,6): how different two bias estimates look."""
    lo = problem["image_offset"] - problem["image_scale"]
    hi = problem["image_offset"] + problem["image_scale"]
    corners = np.stack(
        [lo, np.stack([hi[:, 0], lo[:, 1]], -1), np.stack([lo[:, 0], hi[:, 1]], -1), hi], axis=1
    )  # (S,4,2)
    d = np.asarray(bias_a, float) - np.asarray(bias_b, float)
    shift = d[:, None, :2] + np.einsum("sij,scj->sci", d[:, 2:].reshape(-1, 2, 2), corners)
    return np.max(np.linalg.norm(shift, axis=-1), axis=1)
