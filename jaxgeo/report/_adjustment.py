"""The report of a bundle adjustment (``jaxgeo adjust``) and of a strip (``jaxgeo strip``).

What an adjustment is judged by first: per image, the residual vectors over the image frame
(are they random, or a pattern the bias model does not hold?), the GCPs and check points on a
map coloured by their error (is the error where the control is thin?), the histograms of the
residuals, and the figures before and after (tables 3-4 of 000_5aba1cb50921f3c6.txt). The
numbers are the result's own (the same as ``report.json``): nothing is recomputed but the
measured pixel of each observation, ``project(adjusted model, adjusted point) - residual``
(the residual's definition), where its vector is drawn.
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Mapping, Sequence

import numpy as np

from ._page import Page, new_figure

FLAG_COLOUR, OK_COLOUR = "#d62728", "#1f77b4"
DETAILED_SCENES = 4
"""Sub-scenes of a strip shown in detail (the worst by their residuals' RMS)."""


def measured_pixels(result) -> np.ndarray:
    """``(m, 2)`` the measured (col, row) of each observation of ``result`` (an
    :class:`~jaxgeo.bundle.AdjustResult`): its adjusted point projected by its adjusted model,
    minus its residual (NaN where the point or the model is missing)."""
    import jax.numpy as jnp

    index = {p: k for k, p in enumerate(result.point_ids)}
    images = np.asarray(result.observation_images)
    points = np.array([index.get(p, -1) for p in result.observation_ids])
    out = np.full((len(points), 2), np.nan)
    for name, model in result.models.items():
        sel = np.flatnonzero((images == name) & (points >= 0))
        if sel.size:
            xy = np.asarray(model.project(jnp.asarray(result.ground[points[sel]])))
            out[sel] = xy - np.asarray(result.residuals_px)[sel]
    return out


def _flags(result) -> tuple[np.ndarray, np.ndarray]:
    blunders = np.asarray(result.blunders, dtype=bool)
    removed = (np.zeros_like(blunders) if result.removed is None
               else np.asarray(result.removed, dtype=bool))  # fmt: skip
    return blunders, removed


def _residual_figure(page: Page, name: str, xy, v, flagged, frame, caption_extra="") -> None:
    """Residual vectors of one image over its frame (``frame``: (cols, rows) or ``None``)."""
    from matplotlib.patches import Rectangle

    ok = np.all(np.isfinite(xy), axis=1) & np.all(np.isfinite(v), axis=1)
    xy, v, flagged = xy[ok], v[ok], flagged[ok]
    if frame is None:
        lo, hi = (np.nanmin(xy, axis=0), np.nanmax(xy, axis=0)) if len(xy) else ((0, 0), (1, 1))
        width, height = max(hi[0] - lo[0], 1.0), max(hi[1] - lo[1], 1.0)
        x0, y0 = lo
    else:
        (width, height), (x0, y0) = frame, (-0.5, -0.5)
    norm = np.hypot(v[:, 0], v[:, 1])
    typical = float(np.percentile(norm[~flagged], 90)) if np.any(~flagged) else 0.0
    typical = typical or (float(norm.max()) if norm.size else 1.0) or 1.0
    longest = float(norm[~flagged].max(initial=0.0))
    typical = max(typical, longest / 4.0)  # the longest not flagged: <= 24 % of the frame
    scale = 0.06 * max(width, height) / typical  # a typical vector: 6 % of the frame
    key = float(f"{typical:.1g}")
    aspect = height / width
    fig = new_figure(int(np.clip(700 * aspect + 120, 320, 820)))
    ax = fig.add_subplot()
    ax.add_patch(Rectangle((x0, y0), width, height, fill=False, ec="0.4", lw=1.0))
    for sel, colour, label in ((~flagged, OK_COLOUR, "residual"),
                               (flagged, FLAG_COLOUR, "gross error (flagged)")):  # fmt: skip
        if np.any(sel):
            q = ax.quiver(xy[sel, 0], xy[sel, 1], v[sel, 0] * scale, v[sel, 1] * scale,
                          color=colour, angles="xy", scale_units="xy", scale=1.0, width=0.0025,
                          label=f"{label} ({int(sel.sum())})")  # fmt: skip
            if colour == OK_COLOUR:
                ax.quiverkey(
                    q, 0.82, 1.04, key * scale, f"{key:g} px", coordinates="axes", labelpos="E"
                )  # (the vectors' scale: U in their drawn units)
    ax.set_xlim(x0 - 0.03 * width, x0 + 1.03 * width)
    ax.set_ylim(y0 + 1.03 * height, y0 - 0.03 * height)  # rows go down, as in the image
    ax.set_aspect("equal")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, 1.12), ncol=2, fontsize=9, frameon=False)
    ax.set_title(f"{name}: residuals x{scale:.3g}", loc="left", pad=28)
    rms = np.sqrt(np.mean(v[~flagged] ** 2, axis=0)) if np.any(~flagged) else (np.nan, np.nan)
    page.figure(fig, f"{name}: residual vectors (adjusted - measured) at the measured pixels, "
                f"drawn {scale:.3g} times their length (the arrow in the corner is {key:g} px); "
                f"red: flagged as gross errors. RMS col/row {rms[0]:.3g}/{rms[1]:.3g} px "
                f"without them{caption_extra}.")  # fmt: skip


def _histograms(page: Page, v: np.ndarray, flagged: np.ndarray, what: str) -> None:
    fig = new_figure(340)
    axes = fig.subplots(1, 2, sharey=True)
    kept = v[~flagged & np.all(np.isfinite(v), axis=1)]
    lim = float(np.percentile(np.abs(kept), 99.5)) * 1.1 if kept.size else 1.0
    lim = lim or 1.0
    bins = np.linspace(-lim, lim, 61)
    for k, (ax, axis) in enumerate(zip(axes, ("column", "row"), strict=True)):
        vals = kept[:, k]
        ax.hist(np.clip(vals, -lim, lim), bins=bins, color=OK_COLOUR, alpha=0.85,
                label=f"RMS {np.sqrt(np.mean(vals**2)) if vals.size else np.nan:.3g} px, "
                f"n = {vals.size}")  # fmt: skip
        ax.set_xlabel(f"{axis} residual (px)")
        ax.legend(fontsize=9, loc="upper right")
    axes[0].set_ylabel("observations")
    page.figure(fig, f"Histograms of the {what} residuals (adjusted - measured, px) without the "
                "gross errors (values beyond the axis counted in the end bins).")  # fmt: skip


def _point_errors(result) -> dict[str, tuple[str, np.ndarray]]:
    """Point id -> (role, ENU error (m)): GCPs adjusted - given, check points estimated -
    true (every check point, flagged or not)."""
    out = {}
    for p, e in zip(result.gcp_ids, np.asarray(result.ground_residuals_m), strict=True):
        out[p] = ("gcp", e)
    rep = result.report_all if result.report_all is not None else result.report
    if rep is not None:
        for p, e in zip(rep.ids, np.asarray(rep.errors_m), strict=True):
            out[p] = ("check", e)
    return out


def _map_figure(page: Page, result, title: str) -> None:
    """GCPs and check points of ``result`` on a lon/lat map coloured by their horizontal
    error (m)."""
    ground = np.asarray(result.ground)
    index = {p: k for k, p in enumerate(result.point_ids)}
    errors = _point_errors(result)
    sets = {}
    for role in ("gcp", "check"):
        ids = [p for p, (r, _) in errors.items() if r == role and p in index]
        sets[role] = (ground[[index[p] for p in ids], :2].reshape(-1, 2),
                      np.array([np.hypot(*errors[p][1][:2]) for p in ids]))  # fmt: skip
    ties = [index[p] for p, r in zip(result.point_ids, result.point_role, strict=True)
            if r == "tie"]  # fmt: skip
    _points_map(page, sets, ground[ties, :2].reshape(-1, 2), title,
                "GCPs (triangles; adjusted - given) and check points (circles; estimated - "
                "true), coloured by their horizontal error (m); tie points in grey.")  # fmt: skip


def _points_map(page: Page, sets, ties, title: str, caption: str) -> None:
    """``sets``: role (``gcp``, ``check``) -> (lon/lat ``(k, 2)``, horizontal error ``(k,)``
    m) drawn coloured by the error; ``ties`` ``(t, 2)`` in grey."""
    from matplotlib.ticker import MaxNLocator

    fig = new_figure(560)
    ax = fig.add_subplot()
    if len(ties):
        ax.scatter(ties[:, 0], ties[:, 1], s=4, c="0.75", label=f"tie ({len(ties)})")
    finite = np.concatenate([e[np.isfinite(e)] for _, e in sets.values()] + [np.zeros(0)])
    vmax = float(finite.max()) if finite.size and finite.max() > 0 else 1.0
    sc = None
    for role, marker in (("gcp", "^"), ("check", "o")):
        lonlat, err = sets.get(role, (np.zeros((0, 2)), np.zeros(0)))
        if len(lonlat):
            sc = ax.scatter(lonlat[:, 0], lonlat[:, 1], c=err, cmap="plasma", vmin=0.0,
                            vmax=vmax, marker=marker, s=70, edgecolors="k",
                            label=f"{'GCP' if role == 'gcp' else 'check point'} "
                            f"({len(lonlat)})")  # fmt: skip
    if sc is not None:
        fig.colorbar(sc, ax=ax, label="horizontal error (m)", shrink=0.85)
    ax.set_xlabel("longitude (°)")
    ax.set_ylabel("latitude (°)")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.xaxis.set_major_locator(MaxNLocator(5))  # (long labels: 147.215 ...)
    every = np.concatenate([ties, *(ll for ll, _ in sets.values())])
    if len(every):  # degrees of longitude shorter than those of latitude
        ax.set_aspect(1.0 / max(np.cos(np.radians(np.nanmean(every[:, 1]))), 0.1),
                      adjustable="datalim")  # fmt: skip
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=9, loc="best")
    ax.set_title(title)
    page.figure(fig, f"Ground points: {caption}")


def _frames_of(images: Mapping) -> dict[str, tuple[float, float]]:
    out = {}
    for name, img in images.items():
        size = getattr(img, "size", None)
        if size:
            out[name] = (float(size[0]), float(size[1]))
    return out


def _before_after(page: Page, direct, result) -> None:
    cols = [(r.title if r is not None else t, r) for t, r in
            (("direct georeferencing", direct), ("adjusted", result.report))]  # fmt: skip
    if result.report_all is not None and result.report_all is not result.report:
        cols.append((result.report_all.title, result.report_all))
    cols = [(t, r) for t, r in cols if r is not None]
    if not cols:
        page.text("No check point: the adjustment is judged by its residuals and s0 alone.")
        return
    header = ["", *(t for t, _ in cols)]
    rows = [["s0", *(r.s0 for _, r in cols)], ["check points", *(r.n for _, r in cols)]]
    for k, axis in enumerate(("east", "north", "up")):
        rows.append([f"check RMS {axis} (m)", *(float(r.rms_m[k]) for _, r in cols)])
    for k, axis in enumerate(("east", "north", "up")):
        rows.append(
            [
                f"check max |{axis}| (m)",
                *(float(max(abs(r.min_m[k]), abs(r.max_m[k]))) for _, r in cols),
            ]
        )
    names = sorted({n for _, r in cols for n in r.images})
    for n in names:
        for k, axis in enumerate(("col", "row")):
            rows.append(
                [
                    f"{n}: RMS {axis} (px)",
                    *((float(r.images[n][k]) if n in r.images else None) for _, r in cols),
                ]
            )
    page.table(header, rows)


def write_adjustment_report(
    run,
    path: str | os.PathLike,
    *,
    direct=None,
    images: Mapping | None = None,
    overwrite: bool = False,
) -> pathlib.Path:
    """Write the HTML report of a bundle adjustment to ``path``.

    ``run``: a :class:`jaxgeo.bundle.FileAdjustment` (``jaxgeo adjust``'s; its direct
    georeferencing and images are used) or an :class:`jaxgeo.bundle.AdjustResult` (then
    ``direct``: the :class:`~jaxgeo.bundle.AccuracyReport` with the given models, and
    ``images``: name -> :class:`~jaxgeo.io.SensorImage`, for the frames, both optional). The
    page holds the figures before and after (s0, check-point RMS and maximum in east/north/up
    metres, per image RMS in px), the counts, the GCPs and check points on a map coloured by
    their horizontal error, the residual histograms, and per image the residual vectors over
    its frame with the gross errors in red. Written atomically; an existing ``path`` only with
    ``overwrite`` (``FileExistsError`` naming it otherwise). Returns ``path``."""
    result = getattr(run, "result", run)
    if direct is None:
        direct = getattr(run, "direct", None)
    frames = _frames_of(images if images is not None else getattr(run, "images", {}) or {})
    bias = getattr(run, "bias", None)
    page = Page("Bundle adjustment report",
                [f"bias model: {bias}" if bias else "bundle adjustment",
                 *(f"note: {n}" for n in getattr(run, "notes", ()))])  # fmt: skip
    _adjustment_sections(page, result, direct, frames, detailed=list(result.models))
    return page.write(path, overwrite)


def _adjustment_sections(page: Page, result, direct, frames, detailed: Sequence[str],
                         block: bool = True) -> None:  # fmt: skip
    """The sections of an adjustment; ``block``: with the counts, the table before and after
    and the map (a strip's level 1 has its own: its ties hold heights, as GCPs do)."""
    blunders, removed = _flags(result)
    roles = list(result.point_role)
    state = "converged" if result.converged else "NOT CONVERGED (the last state is shown)"
    how = "" if result.message in ("converged", "") else f" ({result.message})"
    if block:
        page.section("Summary")
    page.text(f"{state}{how} in {result.num_steps} steps; s0 = {result.s0:.3f}, redundancy "
              f"{result.redundancy}; {int(blunders.sum())} observations flagged as gross "
              f"errors, {int(removed.sum())} removed.", warn=not result.converged)  # fmt: skip
    if result.poor_fit:
        page.text(f"POOR FIT: {result.poor_fit}", warn=True)
    if block:
        _counts(page, result, roles, blunders, removed)
        page.section("Before and after")
        _before_after(page, direct, result)
    if block and any(r in ("gcp", "check") for r in roles):
        page.section("Ground control and check points")
        _map_figure(page, result, "GCPs and check points")
    page.section("Residual histograms")
    v = np.asarray(result.residuals_px)
    _histograms(page, v, blunders, "image")
    page.section("Residuals per image")
    xy = measured_pixels(result)
    images = np.asarray(result.observation_images)
    for name in detailed:
        sel = images == name
        if np.any(sel):
            _residual_figure(page, name, xy[sel], v[sel], blunders[sel], frames.get(name))


def _counts(page: Page, result, roles, blunders, removed) -> None:
    page.table(("count", "value"), [
        ("images", len(result.models)), ("observations", len(result.observation_ids)),
        ("GCPs", roles.count("gcp")), ("check points", roles.count("check")),
        ("tie points", roles.count("tie")),
        ("observations flagged as gross errors", int(blunders.sum())),
        ("of them removed", int(removed.sum())),
        ("GCPs flagged / removed", f"{len(result.gcp_flagged)} / {len(result.gcp_removed)}"),
        ("snooping rounds", result.snooping_rounds),
    ])  # fmt: skip


def write_strip_report(run, path: str | os.PathLike, *, overwrite: bool = False) -> pathlib.Path:
    """Write the HTML report of a strip adjustment to ``path``: ``run``, a
    :class:`jaxgeo.strip.StripFileAdjustment` (``jaxgeo strip``'s) or its
    :class:`~jaxgeo.strip.StripResult`. The page holds the whole strip's figures (check RMS and
    tie gaps per stage: direct, level 1, level 2), per sub-scene a summary plot (check RMS per
    stage, the level-1 residual RMS, the GCP scenes marked), the tie gaps per pair, the ground
    points on a map, the residual histograms and, in detail, the residual vectors of the
    :data:`DETAILED_SCENES` worst sub-scenes (readable at 80 scenes). Written atomically; an
    existing ``path`` only with ``overwrite``. Returns ``path``."""
    result = getattr(run, "result", run)
    rep, level1 = result.report, result.level1
    names = list(result.strip.names)
    page = Page("Strip adjustment report", [f"{len(names)} sub-scenes, level-2 correction "
                                            f"{rep.strip.get('degree')}"])  # fmt: skip
    page.section("Whole strip")
    stages = ("direct", "level1", "level2")
    check = rep.strip.get("check_rms_m", {})
    gaps = rep.strip.get("tie_gap_m", {})
    page.table(("stage", "check RMS E (m)", "check RMS N (m)", "check RMS plan (m)",
                "tie gap RMS (m)", "tie gap max (m)"),
               [(st, check.get(st, {}).get("e"), check.get(st, {}).get("n"),
                 check.get(st, {}).get("plan"), gaps.get(st, {}).get("rms"),
                 gaps.get(st, {}).get("max")) for st in stages])  # fmt: skip
    page.table(("", "value"), [(k, rep.strip[k]) for k in
                               ("scenes", "n_gcp", "n_check", "n_ties", "s0", "steps", "converged")
                               if k in rep.strip])  # fmt: skip
    v = np.asarray(level1.residuals_px)
    blunders, _ = _flags(level1)
    images = np.asarray(level1.observation_images)
    scene_rms = []
    for n in names:
        sel = (images == n) & ~blunders
        scene_rms.append(float(np.sqrt(np.mean(np.sum(v[sel] ** 2, axis=1)))) if sel.any()
                         else np.nan)  # fmt: skip
    page.section("Per sub-scene")
    _scene_summary(page, rep, names, np.asarray(scene_rms))
    if rep.pairs:
        _pair_figure(page, rep)
    page.section("Ground control and check points")
    _strip_map(page, result)
    page.section("Level 1 in detail")
    order = [names[k] for k in np.argsort(-np.nan_to_num(np.asarray(scene_rms), nan=-1.0))]
    worst = order[:DETAILED_SCENES]
    frames = {s.name: (float(s.n_cols), float(s.n_rows)) for s in result.strip.scenes}
    page.text(
        f"The level-1 bundle adjustment (biases per sub-scene); residual vectors of the "
        f"{len(worst)} sub-scenes with the largest residual RMS: {', '.join(worst)}."
    )
    _adjustment_sections(page, level1, None, frames, worst, block=False)
    return page.write(path, overwrite)


def _strip_map(page: Page, result) -> None:
    """The strip's GCPs and check points coloured by their level-2 horizontal error (m): per
    point the largest over its measurements."""
    strip, rows = result.strip, result.report.rows
    obs, ground = strip.observations, strip.ground
    where = dict(zip(ground.ids, np.asarray(ground.lonlath)[:, :2], strict=True))
    errors = {"gcp": np.asarray(result.solution.gcp_error_level2_m),
              "check": np.asarray(result.evaluation.check_error_level2_m)}  # fmt: skip
    sets = {}
    for role, err in errors.items():
        worst: dict[str, float] = {}
        measured = list(rows.get(role, []))
        if len(measured) != len(err):  # (not the rows of these errors: drawn without them)
            err = np.full((len(measured), 2), np.nan)
        for i, e in zip(measured, err, strict=True):
            p = obs.point_ids[i]
            worst[p] = np.fmax(worst.get(p, np.nan), float(np.hypot(*e)))
        ids = [p for p in worst if p in where]
        sets[role] = (np.array([where[p] for p in ids]).reshape(-1, 2),
                      np.array([worst[p] for p in ids]))  # fmt: skip
    _points_map(page, sets, np.zeros((0, 2)), "GCPs and check points after level 2",
                "GCPs (triangles) and check points (circles) of the strip, coloured by their "
                "largest horizontal error after level 2 (m; estimate - surveyed).")  # fmt: skip


def _scene_summary(page: Page, rep, names: Sequence[str], scene_rms: np.ndarray) -> None:
    k = np.arange(len(names))
    fig = new_figure(520)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(3, 2))
    styles = {"direct": ("0.5", "--"), "level1": ("#ff7f0e", "-"), "level2": ("#2ca02c", "-")}
    for st, (colour, ls) in styles.items():
        plan = np.array([r.get(st, {}).get("plan", np.nan) for r in rep.scenes], dtype=float)
        top.plot(k, plan, ls, color=colour, marker=".", label=f"{st}")
    gcp = [i for i, r in enumerate(rep.scenes) if r.get("gcp")]
    for i in gcp:
        top.axvspan(i - 0.5, i + 0.5, color="#9edae5", alpha=0.4, lw=0)
    top.set_yscale("log")  # direct: tens of metres; adjusted: decimetres
    top.set_ylabel("check RMS plan (m)")
    top.legend(title="stage", fontsize=9, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    top.set_title("per sub-scene (shaded: sub-scenes with GCPs)")
    bottom.bar(k, scene_rms, color=OK_COLOUR, width=0.8)
    bottom.set_ylabel("level-1 residual RMS (px)")
    bottom.set_xlabel("sub-scene (strip order)")
    step = max(1, len(names) // 20)
    bottom.set_xticks(k[::step], [names[i] for i in k[::step]], rotation=60, fontsize=8,
                      ha="right")  # fmt: skip
    page.figure(
        fig,
        "Top: check-point RMS in plan (m) per sub-scene with the given RPCs "
        "(direct), after level 1 and after level 2; bottom: the RMS length of the "
        "level-1 image residuals per sub-scene (px, gross errors left out).",
    )


def _pair_figure(page: Page, rep) -> None:
    from matplotlib.ticker import MaxNLocator

    fig = new_figure(320)
    ax = fig.add_subplot()
    k = np.arange(len(rep.pairs))
    for st, colour in (("direct", "0.5"), ("level1", "#ff7f0e"), ("level2", "#2ca02c")):
        ax.plot(k, [p.get(st, {}).get("rms", np.nan) for p in rep.pairs], ".-", color=colour,
                label=st)  # fmt: skip
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("adjacent pair (strip order)")
    ax.set_ylabel("tie gap RMS (m)")
    ax.legend(title="stage", fontsize=9)
    page.figure(fig, "Continuity: the RMS ground gap of the ties between adjacent sub-scenes "
                "(m), per pair and stage.")  # fmt: skip
