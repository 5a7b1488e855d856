"""The two-level strip adjustment as one pure function of arrays (jit, vmap).

Level 1 is :func:`jaxgeo.lsq.solve` on the strip's problem (affine bias per sub-scene,
formed ties with height priors, GCPs where they exist). Level 2 localises every GCP measurement
with its level-1 model at the GCP's surveyed height, fits the universal correction of 003_
eq. 12-13 to the differences, and applies it; check points are localised the same way (mono-
plotting at their surveyed height, as an ortho does) before and after the correction.
Everything happens inside :func:`two_level`, so a batch of strips (or Monte-Carlo draws of one
strip's measurements) is one ``vmap`` of one compiled function. Gross errors are found around
it, host side (:mod:`._snooping`): the level-1 observations removed enter as masks, the level-2
GCP measurements removed as zero weights (``Level2Data.gcp_weight``).
"""

from __future__ import annotations

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .. import lsq
from .._runtime.kept import kept
from ..geodesy import metres_per_unit
from ..lsq import Problem, SolverConfig
from ._config import STRIP_SOLVER
from ._level2 import Level2Data
from ._universal import N_TERMS, UniversalCorrection, cross_validate, fit_correction


class TwoLevelSolution(eqx.Module):
    """Output of :func:`two_level`: the level-1 solution, the universal correction, the GCPs'
    level-1 positions with their ``(east, north)`` errors (m, estimate - surveyed), and the
    leave-one-GCP-scene-out RMS (m) of every degree of ``universal.N_TERMS`` (``cv_rms_m``)
    with the index of the degree used (``degree_index``)."""

    level1: lsq.Solution
    correction: UniversalCorrection
    cv_rms_m: Float[Array, " d"]
    degree_index: Int[Array, ""]
    gcp_level1: Float[Array, "g 3"]
    gcp_error_level1_m: Float[Array, "g 2"]
    gcp_error_level2_m: Float[Array, "g 2"]


class Evaluation(eqx.Module):
    """Output of :func:`evaluate`; errors are ``(east, north)`` metres, estimate - surveyed.

    ``check_error_*_m`` (c, 2) per check measurement; ``tie_gap_*_m`` (t, 2): ground position of
    a tie localised in its second sub-scene minus in its first, at the tie's height, with the
    vendor (``before``), level-1 and level-2 models.
    """

    check_error_before_m: Float[Array, "c 2"]
    check_error_level1_m: Float[Array, "c 2"]
    check_error_level2_m: Float[Array, "c 2"]
    tie_gap_before_m: Float[Array, "t 2"]
    tie_gap_level1_m: Float[Array, "t 2"]
    tie_gap_level2_m: Float[Array, "t 2"]


def _take(tree, index):
    return jax.tree.map(lambda x: x[index] if eqx.is_array(x) else x, tree)


def localize_in(blocks, scene, xy, h) -> Float[Array, "n 3"]:
    """Localise ``xy`` (n, 2) at ``h`` (n,) with the stacked sub-scene models ``blocks[scene]``."""
    if scene.shape[0] == 0:
        return jnp.zeros((0, 3))
    return jax.vmap(lambda m, p, z: m.localize(p, z))(_take(blocks, scene), xy, h)


def localize_together(sets: tuple, queries: list[tuple]) -> list[Float[Array, "n 3"]]:
    """:func:`localize_in` of several queries in one localisation: ``sets`` stacked sub-scene
    models of one structure (e.g. vendor and adjusted), ``queries`` ``(set, scene, xy, h)``
    each; the results in the order of ``queries``. One vmapped localisation is traced and
    compiled instead of one per query: the strip's evaluation traced six, ~40 % of a cold
    ``jaxgeo strip`` (80 sub-scenes)."""
    first = sets[0]
    n_scenes = jax.tree.leaves(eqx.filter(first, eqx.is_array))[0].shape[0]
    blocks = jax.tree.map(lambda *xs: jnp.concatenate(xs) if eqx.is_array(xs[0]) else xs[0], *sets)
    scene = jnp.concatenate([jnp.asarray(q[1]) + q[0] * n_scenes for q in queries])
    xy = jnp.concatenate([jnp.asarray(q[2]) for q in queries])
    h = jnp.concatenate([jnp.asarray(q[3]) for q in queries])
    out = localize_in(blocks, scene, xy, h)
    bounds = list(itertools.accumulate(q[1].shape[0] for q in queries))[:-1]
    return list(jnp.split(out, bounds))


def en_error_m(estimate: Float[Array, "n 3"], reference: Float[Array, "n 3"]):
    """``(east, north)`` metres of ``estimate - reference`` (local linearisation; cm-exact)."""
    return ((estimate - reference) * metres_per_unit(reference))[:, :2]


def degree_index(degree: str | Int[Array, ""]) -> Int[Array, ""]:
    """Index of a universal-correction degree in ``universal.N_TERMS``; ``"auto"`` -> -1.

    Passing the index (an array) rather than the name to the jitted functions lets one
    compilation serve every degree."""
    if isinstance(degree, str):
        if degree != "auto" and degree not in N_TERMS:
            raise ValueError(f"degree must be one of {[*N_TERMS, 'auto']}, got {degree!r}")
        return jnp.asarray(-1 if degree == "auto" else list(N_TERMS).index(degree))
    return jnp.asarray(degree)


def level_two(
    problem: Problem,
    data: Level2Data,
    level1: lsq.Solution,
    degree: str | Int[Array, ""] = "quadratic",
) -> TwoLevelSolution:
    """Level 2 on a level-1 solution: every GCP measurement localised with its level-1 model at
    the GCP's surveyed height, the universal correction fitted to them with the weights
    ``data.gcp_weight`` (``degree`` one of ``universal.N_TERMS`` or ``"auto"``: the one with the
    lowest leave-one-GCP-scene-out error; or its :func:`degree_index`)."""
    (group,) = problem.groups
    return TwoLevelSolution(level1, *_level_two(group, data, level1.theta[0], degree))


def _level_two(group, data: Level2Data, theta, degree):
    """:func:`level_two`'s fields after ``level1``, from the model group and level-1 parameters
    only (not the level-1 problem and solution, whose shapes depend on the level-1
    observations: :func:`level_two_jit` then compiles once per strip layout)."""
    adjusted = group.blocks(theta)
    w = data.gcp_weight
    gcp1 = localize_in(adjusted, data.gcp_scene, data.gcp_xy, data.gcp_lonlath[:, 2])
    # the degrees are compared on the GCPs kept, unweighted: a robust loss' weights belong to
    # one degree's fit, and would make the comparison depend on the degree that chose them
    keep = (w > 0).astype(gcp1.dtype)
    cv = cross_validate(gcp1, data.gcp_lonlath, data.gcp_group, metres_per_unit(gcp1), keep)
    wanted = degree_index(degree)  # -1: auto, the degree that best predicts GCP scenes left out
    index = jnp.where(wanted < 0, jnp.argmin(jnp.where(jnp.isfinite(cv), cv, jnp.inf)), wanted)
    fits = [fit_correction(gcp1, data.gcp_lonlath, d, weight=w) for d in N_TERMS]
    corr = jax.tree.map(lambda *c: jnp.stack(c)[index], *fits)
    return (
        corr,
        cv,
        index,
        gcp1,
        en_error_m(gcp1, data.gcp_lonlath),
        en_error_m(corr.apply(gcp1), data.gcp_lonlath),
    )


def two_level(
    problem: Problem,
    data: Level2Data,
    degree: str | Int[Array, ""] = "quadratic",
    solver: SolverConfig = STRIP_SOLVER,
    *,
    removed_image: Bool[Array, " M"] | None = None,
    removed_ground: Bool[Array, " c"] | None = None,
) -> TwoLevelSolution:
    """Level 1 (bundle adjustment of ``problem`` with ``solver``, robust loss included, one
    model group of single-image blocks, one block per sub-scene in strip order; the
    ``removed_*`` observations out, as :func:`jaxgeo.lsq.solve` takes them) then
    :func:`level_two`. One pure function (jit, vmap); the data snooping that finds what to
    remove runs around it (:func:`~._adjustment.adjust_strip`)."""
    sol = lsq.solve(problem, solver, removed_image=removed_image, removed_ground=removed_ground)
    return level_two(problem, data, sol, degree)


def evaluate(problem: Problem, data: Level2Data, sol: TwoLevelSolution) -> Evaluation:
    """Check-point errors and tie gaps of the vendor, level-1 and level-2 models."""
    (group,) = problem.groups
    return _evaluate(group, data, sol.level1.theta[0], sol.correction)


def _evaluate(group, data: Level2Data, theta, corr: UniversalCorrection) -> Evaluation:
    """:func:`evaluate` from the model group, the level-1 parameters and the correction only
    (:func:`evaluate_jit` then compiles once per strip layout)."""
    vendor, adjusted = group.blocks(group.theta0), group.blocks(theta)  # sets 0 and 1
    chk = (data.check_scene, data.check_xy, data.check_lonlath[:, 2])
    tie = [(data.tie_scene[:, i], data.tie_xy[:, i], data.tie_h) for i in (0, 1)]
    # the ties localised with the level-1 models once, for the level-1 and level-2 gaps
    chk0, chk1, v0, v1, a0, a1 = localize_together(
        (vendor, adjusted), [(0, *chk), (1, *chk), (0, *tie[0]), (0, *tie[1]), (1, *tie[0]),
                             (1, *tie[1])],
    )  # fmt: skip
    return Evaluation(
        check_error_before_m=en_error_m(chk0, data.check_lonlath),
        check_error_level1_m=en_error_m(chk1, data.check_lonlath),
        check_error_level2_m=en_error_m(corr.apply(chk1), data.check_lonlath),
        tie_gap_before_m=en_error_m(v1, v0),
        tie_gap_level1_m=en_error_m(a1, a0),
        tie_gap_level2_m=en_error_m(corr.apply(a1), corr.apply(a0)),
    )


two_level_jit = eqx.filter_jit(two_level)
# kept programs (traced once per strip layout, across runs too); ``level_two`` and ``evaluate``
# call the functions themselves, inlined in their callers' programs
_kept_level_two, _kept_evaluate = kept(_level_two), kept(_evaluate)


def level_two_jit(
    problem: Problem,
    data: Level2Data,
    level1: lsq.Solution,
    degree: str | Int[Array, ""] = "quadratic",
) -> TwoLevelSolution:
    """:func:`level_two` compiled once per strip layout (model group and level-2 data): level-1
    problems of one strip with or without GCPs share it."""
    (group,) = problem.groups
    return TwoLevelSolution(level1, *_kept_level_two(group, data, level1.theta[0], degree))


def evaluate_jit(problem: Problem, data: Level2Data, sol: TwoLevelSolution) -> Evaluation:
    """:func:`evaluate` compiled once per strip layout (as :func:`level_two_jit`)."""
    (group,) = problem.groups
    return _kept_evaluate(group, data, sol.level1.theta[0], sol.correction)


@eqx.filter_jit
def two_level_batch(
    problem: Problem,
    data: Level2Data,
    xy: Float[Array, "b m 2"],
    gcp_xy: Float[Array, "b g 2"],
    check_xy: Float[Array, "b c 2"],
    degree: str | Int[Array, ""] = "quadratic",
    solver: SolverConfig = STRIP_SOLVER,
) -> tuple[TwoLevelSolution, Evaluation]:
    """:func:`two_level` and :func:`evaluate` for a batch of measurement sets of one strip
    structure: ``xy`` the problem's concatenated image observations, ``gcp_xy``/``check_xy``
    those of level 2, per batch item. One compiled call (Monte-Carlo runs, or many strips of
    one layout), the items one after another (``lax.map``), not vmapped: a strip's reduced
    system is factorised by LAPACK, and jaxlib's batched (vmapped) LAPACK kernels deadlock on
    a 2-core CPU (seen in this call: both XLA threads waiting in ``ParallelBatchMap`` inside
    ``dpotrf``, the test suite hung)."""

    def one(xy_b, gcp_b, check_b):
        d = eqx.tree_at(lambda t: (t.gcp_xy, t.check_xy), data, (gcp_b, check_b))
        p = problem.with_xy(xy_b)
        sol = two_level(p, d, degree, solver)
        return sol, evaluate(p, d, sol)

    return jax.lax.map(lambda args: one(*args), (xy, gcp_xy, check_xy))
