"""``adjust_strip``: the two-level full-strip adjustment of 003_ (sections 6-9), tables in.

1. the GCP distribution rule of section 9 is checked (a :class:`GCPDistributionWarning` names
   the gaps);
2. level 1: ties formed from the sub-scenes' line offsets, one bundle adjustment of all
   sub-scenes (affine bias each) with the ties and the GCPs where they exist;
3. level 2: the universal correction (eq. 12-13) fitted to the GCPs' level-1 positions and
   applied to every sub-scene; updated RPCs on request (:meth:`StripResult.updated_rpcs`).

Gross errors (:mod:`._snooping`): both levels use the solver's robust loss (Cauchy by default,
IRLS) and data snooping (w-test, the flagged observations removed and re-solved); a sub-scene
whose line offset is wrong is named from the seams before solving
(:class:`~._errors.LineOffsetWarning`). :func:`._solve.two_level` is both levels as one compiled
function; vmapped, it adjusts a batch (:func:`._batch.monte_carlo`). :func:`adjust_individually`
is the practice the paper compares with: every sub-scene adjusted to its own GCPs.
"""

from __future__ import annotations

import copy
import dataclasses
import time
import warnings
from collections.abc import Mapping
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..bundle import AdjustmentError, AdjustResult, Prepared, prepare, with_bias
from ..bundle.internal import make_result, snoop
from ..io import GroundPoints, Observations
from ..lsq import SolverConfig
from ..lsq.internal import DEFAULT_SOLVER
from ..models import localize_points
from ..models.internal import BIAS_KINDS
from ._config import StripConfig
from ._delivery import Strip
from ._distribution import check_gcp_distribution
from ._errors import LineOffsetWarning, UniversalCorrectionWarning
from ._level1 import level1_input
from ._level2 import Level2Data, level2_input
from ._report import GrossErrors, line_offset_message, strip_report
from ._result import StripResult
from ._snooping import seam_offsets, snoop_level2, suspect_offsets
from ._solve import en_error_m, evaluate_jit, localize_together
from ._universal import N_TERMS, UniversallyCorrected, check_design

N_BIAS_GCPS = {name: kind().n_params // 2 for name, kind in BIAS_KINDS.items()}
"""GCPs one sub-scene needs to be adjusted on its own with each bias (two equations each)."""


def _in_level1(err: AdjustmentError, strip: Strip) -> AdjustmentError:
    """``err`` (same type and attributes) with the level-1 context and the strip's file."""
    where = strip.files.description if strip.files is not None else "the strip"
    out = copy.copy(err)
    out.args = (f"level-1 bundle adjustment of {where}: {err}", *err.args[1:])
    return out


def adjust_strip(strip: Strip, config: StripConfig | None = None) -> StripResult:
    """Two-level adjustment of a strip (see the module docstring).

    Args:
        strip: sub-scenes with vendor RPCs, ground points, measurements (:func:`read_strip`).
        config: the ties, both levels and the level-1 solver (:class:`~._config.StripConfig`;
            default ``StripConfig()``, 003_'s settings). A fixed universal-correction degree whose
            leave-one-GCP-scene-out error exceeds the best one's by half warns
            (:class:`UniversalCorrectionWarning`): with few GCP scenes a quadratic fits their
            noise and degrades the scenes between them.

    Gross errors: level 1 is snooped as :func:`jaxgeo.adjust` does
    (:func:`jaxgeo.bundle.snoop`), level 2 with the same settings on the GCP
    measurements left (:func:`._snooping.snoop_level2`); ``result.gross_errors`` and the report
    list them. A broken seam warns (:class:`~._errors.LineOffsetWarning`) naming the sub-scene.

    Raises a :class:`~._errors.ConfigError` naming the setting (ties only without bias priors,
    too few or aligned GCPs for the correction), after the GCP distribution warning, and the
    bundle adjustment's :class:`~jaxgeo.bundle.AdjustmentError` with the strip named.
    """
    t0 = time.perf_counter()
    config = StripConfig() if config is None else config
    names = strip.names
    if len(names) < 2:
        raise ValueError("a strip adjustment needs at least two sub-scenes")
    dist = check_gcp_distribution(
        len(names), strip.gcp_scenes(), names, warn=config.check_distribution
    )
    config.level1.check_priors()  # after the distribution warning: it says what to add
    degree = config.level2.degree
    inp = level1_input(strip, config.ties, use_gcps=config.level1.use_gcps)
    models = with_bias({n: strip.rpcs[n] for n in names}, config.level1.bias)
    try:
        setup = prepare(
            models,
            inp.observations,
            inp.ground,
            prior_sigma=config.level1.prior_sigma(models[names[0]]),
            check_control=False,
        )
    except AdjustmentError as err:
        raise _in_level1(err, strip) from err
    setup = unsliced(setup)
    if len(setup.problem.groups) != 1:
        raise ValueError(
            "the sub-scene RPCs of a strip must share one structure (term order, shapes); got "
            f"{len(setup.problem.groups)} kinds"
        )
    block_of = np.array([setup.image_index[n][1] for n in names])
    data, rows = level2_input(strip, inp, block_of, _gsd_m(strip))
    where = f"{strip.files.ground}: " if strip.files is not None else ""
    check_design(
        np.asarray(data.gcp_lonlath), "shift" if degree in ("auto", "none") else degree, where
    )
    suspects = suspect_offsets(strip, seam_offsets(strip, inp))
    if suspects:
        warnings.warn(line_offset_message(suspects), LineOffsetWarning, stacklevel=2)
    t1 = time.perf_counter()
    sol1, rem_i, rem_g, rounds = snoop(setup, config.solver)
    try:
        level1 = make_result(
            setup, sol1, inp.observations, inp.ground, config.solver, (rem_i, rem_g), rounds
        )
    except AdjustmentError as err:
        raise _in_level1(err, strip) from err
    l2 = snoop_level2(
        setup.problem,
        data,
        sol1,
        degree,
        config.solver,
        _removed_at_level1(level1, inp, rows, strip),
    )
    sol = jax.block_until_ready(l2.solution)
    data = eqx.tree_at(lambda t: t.gcp_weight, data, jnp.asarray(l2.weight))
    t2 = time.perf_counter()
    ev = evaluate_jit(setup.problem, data, sol)
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
    gross = GrossErrors.collect(
        level1, l2, rows, strip, suspects, config.solver, inp.tie_ids + inp.measured_ids,
        np.asarray(ev.check_error_level2_m),
    )  # fmt: skip
    report = strip_report(strip, sol, ev, rows, inp, setup.problem.n_unknowns, used, gross)
    return StripResult(
        strip=strip,
        models=final,
        level1=level1,
        correction=corr,
        distribution=dist,
        report=report,
        config=config,
        solution=sol,
        evaluation=ev,
        inputs=inp,
        data=data,
        timings_s={"setup": t1 - t0, "first_call": t2 - t1},
        gross_errors=gross,
    )


def unsliced(setup: Prepared) -> Prepared:
    """``setup`` with its image residuals evaluated per observation, not block by block.

    :func:`~jaxgeo.bundle.prepare` sorts an image slot's observations by block when the
    blocks are about equally observed and evaluates each block's padded slice with its own
    model (``ImageObs.block_start``). For a strip (one block per sub-scene, a few hundred
    observations) the per-observation evaluation runs as fast, and it keeps the strip's
    numbers those of its benchmarks and tests (the two differ by rounding, <= 4e-9 px). The
    observations stay in the same (block-sorted) order; only the static ``block_start`` goes.
    """
    p = setup.problem
    if not any(ob.block_start for ob in p.images):
        return setup
    images = tuple(dataclasses.replace(ob, block_start=()) for ob in p.images)
    return dataclasses.replace(setup, problem=dataclasses.replace(p, images=images))


def _gsd_m(strip: Strip) -> np.ndarray:
    """Ground sample distance (m) of every sub-scene at its centre, from its vendor RPC."""
    out = []
    for s in strip.scenes:
        rpc = strip.rpcs[s.name]
        c = np.array([[0.5 * (s.n_cols - 1), 0.5 * (s.n_rows - 1)]])
        xy = np.concatenate([c, c + [1.0, 0.0], c + [0.0, 1.0]])
        g = localize_points(rpc, xy, np.full(3, float(rpc.ground_offset[2])))
        d = np.asarray(en_error_m(jnp.asarray(g[1:]), jnp.asarray(g[[0, 0]])))
        out.append(float(np.sqrt(np.mean(np.sum(d**2, axis=1)))))
    return np.array(out)


def _removed_at_level1(level1: AdjustResult, inp, rows: dict, strip: Strip) -> np.ndarray:
    """The level-2 GCP measurements (g,) whose level-1 image observation or GCP coordinates
    were removed as gross errors."""
    o = inp.observations
    n_tie = len(inp.ties.point)
    removed = level1.removed if level1.removed is not None else np.zeros(len(o.point_ids), bool)
    gone = {
        key
        for i, key in enumerate(zip(o.point_ids, o.images, strict=True))
        if i >= n_tie and removed[i]
    }
    so = strip.observations
    return np.array(
        [(so.point_ids[i], so.images[i]) in gone or so.point_ids[i] in level1.gcp_removed
         for i in rows["gcp"]],
        dtype=bool,
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
    chk, t0, t1 = localize_together(
        (blocks,),
        [(0, d.check_scene, d.check_xy, d.check_lonlath[:, 2])]
        + [(0, d.tie_scene[:, i], d.tie_xy[:, i], d.tie_h) for i in (0, 1)],
    )
    return en_error_m(chk, d.check_lonlath), en_error_m(t1, t0)


def adjust_individually(
    strip: Strip, bias: str = "affine", solver: SolverConfig | None = None
) -> tuple[dict[str, Any], AdjustResult | None]:
    """Each sub-scene adjusted on its own with its own GCPs (the practice that leaves the
    discontinuities of 003_ figure 2). Returns ``(models, result)``: every sub-scene's model
    (vendor RPC with a zero bias where the scene has too few GCPs for ``bias``) and the
    :class:`~jaxgeo.bundle.AdjustResult` of the adjusted scenes (one block-diagonal
    bundle solved with ``solver``, default :func:`jaxgeo.adjust`'s; ``None`` if no scene has
    enough GCPs)."""
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
    solver = DEFAULT_SOLVER if solver is None else solver
    # jaxgeo.adjust's three stages, with the per-observation residuals of the strip (unsliced)
    setup = unsliced(prepare({n: models[n] for n in todo}, obs, ground, check_control=False))
    sol, rem_i, rem_g, rounds = snoop(setup, solver)
    res = make_result(setup, sol, obs, ground, solver, (rem_i, rem_g), rounds)
    models.update(res.models)
    return models, res
