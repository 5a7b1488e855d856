"""``adjust_strip``: the two-level full-strip adjustment of 003_ (sections 6-9), tables in.

1. the GCP distribution rule of section 9 is checked (a :class:`GCPDistributionWarning` names
   the gaps);
2. level 1: ties formed from the sub-scenes' line offsets, one bundle adjustment of all
   sub-scenes (affine bias each) with the ties and the GCPs where they exist;
3. level 2: the universal correction (eq. 12-13) fitted to the GCPs' level-1 positions and
   applied to every sub-scene; updated RPCs on request (:meth:`StripResult.updated_rpcs`).

Both levels run as one compiled function (:func:`.pipeline.two_level`); the same function,
vmapped, adjusts a batch (:func:`monte_carlo`).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..adjust.setup import Setup, build
from ..adjust.solve import AdjustResult, adjust, finish, with_bias
from ..io.tables import GroundPoints, Observations
from ..models.rpc import RPC
from ..models.rpc_fit import RPCFitReport, fit_rpcs
from .data import Strip
from .distribution import DistributionCheck, check_gcp_distribution
from .level1 import (
    TIE_HEIGHT_SIGMA_M,
    TIE_MARGIN_PX,
    TIE_SIGMA_PX,
    Level1Input,
    TieHeight,
    level1_input,
)
from .pipeline import (
    Evaluation,
    Level2Data,
    TwoLevelSolution,
    degree_index,
    en_error_m,
    evaluate_jit,
    localize_in,
    tie_gap,
    two_level_batch,
    two_level_jit,
)
from .report import StripReport, strip_report
from .universal import N_TERMS, UniversalCorrection, UniversallyCorrected, check_design


class UniversalCorrectionWarning(UserWarning):
    """The chosen universal correction predicts GCP scenes left out worse than a simpler one."""


N_BIAS_GCPS = {"shift": 1, "shift-drift": 2, "affine": 3}
"""GCPs one sub-scene needs to be adjusted on its own with each bias."""


@dataclasses.dataclass(frozen=True)
class StripResult:
    """The adjusted strip.

    ``models``: sub-scene name -> final model (level-1 biased RPC + universal correction);
    ``level1``: the level-1 bundle (:class:`~jaxgeo.adjust.AdjustResult`: biases with sigmas,
    s0, tie residuals); ``correction``: the universal correction; ``report``: per sub-scene
    absolute accuracy and continuity (:class:`~.report.StripReport`); ``solution``: the raw
    arrays of :func:`~.pipeline.two_level`; ``timings_s``: setup, solve (both levels, compiled
    call) and compile time of the first call.
    """

    strip: Strip
    models: dict[str, UniversallyCorrected]
    level1: AdjustResult
    correction: UniversalCorrection
    distribution: DistributionCheck
    report: StripReport
    solution: TwoLevelSolution = dataclasses.field(repr=False)
    evaluation: Evaluation = dataclasses.field(repr=False)
    inputs: Level1Input = dataclasses.field(repr=False)
    data: Level2Data = dataclasses.field(repr=False)
    options: dict = dataclasses.field(repr=False)
    timings_s: dict = dataclasses.field(default_factory=dict)

    @property
    def setup(self) -> Setup:
        return self.level1.setup

    def updated_rpcs(
        self,
        h_range: Sequence[float] | None = None,
        grid: tuple[int, int, int] = (21, 21, 7),
        names: Sequence[str] | None = None,
    ) -> dict[str, tuple[RPC, RPCFitReport]]:
        """RPCs refitted to the final sub-scene models (all, or ``names``): terrain-independent
        grid over the image and ``h_range`` (default the vendor RPC's height range), with fit
        reports."""
        out = {}
        scenes = {s.name: s for s in self.strip.scenes}
        for name in names if names is not None else self.strip.names:
            model = self.models[name]
            rpc = self.strip.rpcs[name]
            if h_range is None:
                h0 = float(rpc.ground_offset[2]) - float(rpc.ground_scale[2])
                h1 = float(rpc.ground_offset[2]) + float(rpc.ground_scale[2])
            else:
                h0, h1 = h_range
            sc = scenes[name]
            ((fit, rep),) = fit_rpcs([model], sc.n_cols, sc.n_rows, (h0, h1), grid=grid)
            out[name] = (fit, rep)
        return out


def _level2_data(strip: Strip, inp: Level1Input, block_of: np.ndarray):
    o, g = strip.observations, strip.ground
    index = {p: i for i, p in enumerate(g.ids)}
    scene = {n: k for k, n in enumerate(strip.names)}
    rows = {"gcp": [], "check": []}
    for i, p in enumerate(o.point_ids):
        if p in index:
            rows[g.role[index[p]]].append(i)
    t = inp.ties
    pair = np.argsort(t.point, kind="stable").reshape(-1, 2)  # (t, 2) rows: scene k, k + 1

    def lonlath(r):
        return jnp.asarray(g.lonlath[[index[o.point_ids[i]] for i in r]].reshape(-1, 3))

    def scenes(r):
        return jnp.asarray(block_of[[scene[o.images[i]] for i in r]].astype(np.int64))

    gcp_scene = np.array([scene[o.images[i]] for i in rows["gcp"]], dtype=int)
    groups = np.unique(gcp_scene)
    group = (gcp_scene[None, :] == groups[:, None]).astype(float).reshape(len(groups), -1)

    return Level2Data(
        gcp_scene=scenes(rows["gcp"]),
        gcp_xy=jnp.asarray(o.xy[rows["gcp"]].reshape(-1, 2)),
        gcp_lonlath=lonlath(rows["gcp"]),
        gcp_group=jnp.asarray(group),
        check_scene=scenes(rows["check"]),
        check_xy=jnp.asarray(o.xy[rows["check"]].reshape(-1, 2)),
        check_lonlath=lonlath(rows["check"]),
        tie_scene=jnp.asarray(block_of[t.scene[pair]].astype(np.int64)),
        tie_xy=jnp.asarray(t.xy[pair]),
        tie_h=jnp.asarray(inp.tie_lonlath[:, 2]),
    ), rows


def adjust_strip(
    strip: Strip,
    *,
    ties_per_pair: int = 50,
    tie_margin_px: float = TIE_MARGIN_PX,
    tie_sigma_px: float = TIE_SIGMA_PX,
    tie_height: TieHeight = None,
    tie_height_sigma_m: float = TIE_HEIGHT_SIGMA_M,
    bias: str = "affine",
    bias_prior_sigma: Any = None,
    level1_gcps: bool = True,
    degree: str = "quadratic",
    method: str = "lm",
    max_steps: int = 50,
    tol: float = 1e-6,
    check_distribution: bool = True,
) -> StripResult:
    """Two-level adjustment of a strip (see the module docstring).

    Args:
        strip: sub-scenes with vendor RPCs, ground points, measurements (:func:`read_strip`).
        ties_per_pair, tie_margin_px: formed ties per adjacent pair, kept this far inside the
            overlap (px); ``tie_sigma_px`` their a priori sigma.
        tie_height: a DEM ``f(lonlat (n, 2)) -> h (n,)``, a constant height (m), or ``None``
            (mean surveyed height); ``tie_height_sigma_m`` the sigma of these height priors.
        bias: image bias per sub-scene (``"affine"`` as in 003_, ``"shift-drift"``,
            ``"shift"``); ``bias_prior_sigma`` optional priors on it (as in
            :func:`jaxgeo.adjust`); needed when ``level1_gcps=False``, where level 1 sees ties
            only (the paper's pure two-level flow) and the biases' common part has no datum.
        degree: universal correction ``"quadratic"`` (eq. 12-13), ``"affine"``, ``"shift"``,
            ``"none"``, or ``"auto"``: the degree that best predicts the GCPs of each GCP scene
            left out in turn. A fixed degree whose leave-one-out error exceeds the best one's
            by half warns (:class:`UniversalCorrectionWarning`): with few GCP scenes a
            quadratic fits their noise and degrades the scenes between them.
        method, max_steps, tol: level-1 solver options (:func:`jaxgeo.adjust.core.solve`).
        check_distribution: warn (:class:`GCPDistributionWarning`) when the GCP scenes break the
            rule of section 9.
    """
    t0 = time.perf_counter()
    names = strip.names
    if len(names) < 2:
        raise ValueError("a strip adjustment needs at least two sub-scenes")
    gcp_scenes = strip.gcp_scenes()
    dist = check_gcp_distribution(len(names), gcp_scenes, names, warn=check_distribution)
    if not level1_gcps and bias_prior_sigma is None:
        raise ValueError(
            "level 1 with ties only (level1_gcps=False) needs bias priors (bias_prior_sigma): "
            "ties fix the biases' differences, not their common part"
        )
    if degree not in N_TERMS and degree != "auto":
        raise ValueError(f"degree must be one of {[*N_TERMS, 'auto']}, got {degree!r}")
    inp = level1_input(
        strip,
        ties_per_pair,
        tie_margin_px=tie_margin_px,
        tie_sigma_px=tie_sigma_px,
        tie_height=tie_height,
        tie_height_sigma_m=tie_height_sigma_m,
        use_gcps=level1_gcps,
    )
    models = with_bias({n: strip.rpcs[n] for n in names}, bias)
    setup = build(
        models, inp.observations, inp.ground, prior_sigma=bias_prior_sigma, check_control=False
    )
    if len(setup.problem.groups) != 1:
        raise ValueError(
            "the sub-scene RPCs of a strip must share one structure (term order, shapes); got "
            f"{len(setup.problem.groups)} kinds"
        )
    block_of = np.array([setup.image_index[n][1] for n in names])
    data, rows = _level2_data(strip, inp, block_of)
    check_design(np.asarray(data.gcp_lonlath), "shift" if degree in ("auto", "none") else degree)
    t1 = time.perf_counter()
    sol = two_level_jit(setup.problem, data, degree_index(degree), method, max_steps, tol)
    sol = jax.block_until_ready(sol)
    t2 = time.perf_counter()
    ev = evaluate_jit(setup.problem, data, sol)
    level1 = finish(setup, sol.level1, inp.observations, inp.ground)
    corr = jax.tree.map(np.asarray, sol.correction)
    final = {n: UniversallyCorrected(level1.models[n], corr) for n in names}
    used = list(N_TERMS)[int(sol.degree_index)]
    cv = np.asarray(sol.cv_rms_m)
    if degree != "auto" and cv[int(sol.degree_index)] > 1.5 * np.nanmin(cv):
        best = list(N_TERMS)[int(np.nanargmin(cv))]
        warnings.warn(
            f"the {used} universal correction predicts the GCPs of a GCP scene left out to "
            f"{cv[int(sol.degree_index)]:.2f} m RMS, the {best} one to {np.nanmin(cv):.2f} m: "
            f"too few GCP scenes for {used}; consider degree='auto' or '{best}'",
            UniversalCorrectionWarning,
            stacklevel=2,
        )
    report = strip_report(strip, sol, ev, rows, inp, setup.problem.n_unknowns, used)
    options = dict(
        ties_per_pair=ties_per_pair, tie_margin_px=tie_margin_px, tie_sigma_px=tie_sigma_px,
        tie_height_sigma_m=tie_height_sigma_m, bias=bias, level1_gcps=level1_gcps,
        degree=degree, method=method, max_steps=max_steps, tol=tol,
    )  # fmt: skip
    return StripResult(
        strip=strip,
        models=final,
        level1=level1,
        correction=corr,
        distribution=dist,
        report=report,
        solution=sol,
        evaluation=ev,
        inputs=inp,
        data=data,
        options=options,
        timings_s={"setup": t1 - t0, "first_call": t2 - t1},
    )


def time_two_level(result: StripResult, repeat: int = 3) -> float:
    """Best wall time (s) of the compiled two-level call on ``result``'s problem."""
    o = result.options
    args = (result.setup.problem, result.data, degree_index(o["degree"]), o["method"],
            o["max_steps"], o["tol"])  # fmt: skip
    jax.block_until_ready(two_level_jit(*args))
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(two_level_jit(*args))
        best = min(best, time.perf_counter() - t)
    return best


def monte_carlo_inputs(
    result: StripResult, n_runs: int, noise_px: float | None = None, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noisy measurement sets for :func:`~.pipeline.two_level_batch`: ``(xy (b, m, 2),
    gcp_xy (b, g, 2), check_xy (b, c, 2))``. Fresh Gaussian noise (``noise_px``, default each
    measurement's a priori sigma) on the GCP and check measurements, the same draw wherever a
    measurement enters (level 1 and level 2); formed ties stay exact."""
    rng = np.random.default_rng(seed)
    data, inp = result.data, result.inputs
    o = result.strip.observations
    rows = result.report.rows
    sigma = o.sigma_px if noise_px is None else np.full(len(o.sigma_px), float(noise_px))
    n_ties = len(inp.ties.point)
    xy, gcp_xy, check_xy = [], [], []
    for _ in range(n_runs):
        e = rng.normal(0.0, 1.0, o.xy.shape) * sigma[:, None]
        e_gcp, e_chk = e[rows["gcp"]], e[rows["check"]]
        noisy = np.array(inp.observations.xy)
        if result.options["level1_gcps"]:
            noisy[n_ties:] += e_gcp  # the level-1 GCP rows, in the order of rows["gcp"]
        xy.append(noisy[result.setup.obs_order])
        gcp_xy.append(np.asarray(data.gcp_xy) + e_gcp)
        check_xy.append(np.asarray(data.check_xy) + e_chk)
    return np.stack(xy), np.stack(gcp_xy), np.stack(check_xy)


def monte_carlo(
    result: StripResult, n_runs: int, noise_px: float | None = None, seed: int = 0
) -> tuple[TwoLevelSolution, Evaluation]:
    """``n_runs`` Monte-Carlo repetitions of ``result``'s two-level adjustment (noise as in
    :func:`monte_carlo_inputs`) in one vmapped, jitted call. Returns the batched solution and
    evaluation (leading axis ``n_runs``)."""
    xy, gcp_xy, check_xy = monte_carlo_inputs(result, n_runs, noise_px, seed)
    o = result.options
    return two_level_batch(
        result.setup.problem, result.data, jnp.asarray(xy), jnp.asarray(gcp_xy),
        jnp.asarray(check_xy), degree_index(o["degree"]), o["method"], o["max_steps"], o["tol"],
    )  # fmt: skip


def evaluate_models(result: StripResult, models: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """Check-point errors ``(c, 2)`` and tie gaps ``(t, 2)`` (east, north m) of any set of
    sub-scene models of one structure (e.g. scenes adjusted one by one), on ``result``'s check
    points and ties: ``{"check_error_m": ..., "tie_gap_m": ...}``."""
    names = result.strip.names
    order = sorted(names, key=lambda n: result.setup.image_index[n][1])  # block order
    blocks = jax.tree.map(lambda *x: jnp.stack(x), *(models[n] for n in order))
    check, gap = _evaluate_blocks(blocks, result.data)
    return {"check_error_m": np.asarray(check), "tie_gap_m": np.asarray(gap)}


@eqx.filter_jit
def _evaluate_blocks(blocks, d: Level2Data):
    h = d.check_lonlath[:, 2]
    check = en_error_m(localize_in(blocks, d.check_scene, d.check_xy, h), d.check_lonlath)
    return check, tie_gap(blocks, d)


def adjust_individually(
    strip: Strip, bias: str = "affine", **options: Any
) -> tuple[dict[str, Any], AdjustResult | None]:
    """Each sub-scene adjusted on its own with its own GCPs (the practice that leaves the
    discontinuities of 003_ figure 2). Returns ``(models, result)``: every sub-scene's model
    (vendor RPC with a zero bias where the scene has too few GCPs for ``bias``) and the
    :class:`~jaxgeo.adjust.AdjustResult` of the adjusted scenes (one block-diagonal bundle;
    ``None`` if no scene has enough GCPs)."""
    models = with_bias(dict(strip.rpcs), bias)
    need = N_BIAS_GCPS[bias]
    g = strip.ground
    index = {p: i for i, p in enumerate(g.ids)}
    o = strip.observations
    rows: dict[str, list[int]] = {n: [] for n in strip.names}
    for i, (p, img) in enumerate(zip(o.point_ids, o.images, strict=True)):
        if p in index and g.role[index[p]] == "gcp":
            rows[img].append(i)
    todo = [n for n in strip.names if len(rows[n]) >= need]
    if not todo:
        return models, None
    # one block-diagonal bundle == independent adjustments: a GCP seen in two sub-scenes gets
    # one copy per sub-scene, so no scene sees another's measurements
    sel = [i for n in todo for i in rows[n]]
    ids = tuple(f"{o.point_ids[i]}@{o.images[i]}" for i in sel)
    obs = Observations(ids, tuple(o.images[i] for i in sel), o.xy[sel], o.sigma_px[sel])
    gi = [index[o.point_ids[i]] for i in sel]
    ground = GroundPoints(ids, g.lonlath[gi], ("gcp",) * len(sel), g.sigma_m[gi])
    res = adjust({n: models[n] for n in todo}, obs, ground, **options)
    models.update(res.models)
    return models, res
