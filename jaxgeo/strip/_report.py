"""Per sub-scene and whole-strip figures of the strip adjustment (003_ table 1 and figure 2).

Absolute: check points localised with each stage's model at their surveyed height (what an
ortho does) minus their surveyed position, east/north metres, RMS per sub-scene. Continuity:
for each adjacent pair, the ground distance between a tie localised in one sub-scene and in the
other at the tie's height -- zero for a seamless mosaic.

Stages: ``direct`` (vendor RPCs), ``level1`` (bundle-adjusted biases), ``level2`` (plus the
universal correction).

No height figures: a strip sees each point from one direction (adjacent sub-scenes share their
overlap lines, so a point's two rays nearly coincide), so the check points are mono-plotted at
their surveyed heights and only their plan error is measured (a height error needs a stereo pair:
``jaxgeo adjust``).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence

import numpy as np

from ..lsq import RESULTS
from ._snooping import CHECK_K, gross_checks
from ._universal import N_TERMS

STAGES = ("direct", "level1", "level2")


@dataclasses.dataclass(frozen=True)
class GrossErrors:
    """The gross errors found in a strip (:mod:`._snooping`).

    ``flagged``: one entry per flagged observation, ``{level, image, id, what, w, removed}``
    (``level`` 1 or 2; ``image`` the sub-scene; ``id`` the point (``tie_*`` a formed tie);
    ``what`` ``"image"`` for a measurement, ``"ground"`` for a GCP's coordinates, ``"tie
    height"`` for a tie's height prior (removed with its rays); ``w`` the
    largest |standardised residual|; ``removed``: left out and re-solved). ``rounds``: re-solves
    at each level; ``line_offsets``: the broken seams (:func:`._snooping.suspect_offsets`);
    ``checks_excluded``: check points left out of the statistics because an observation of
    theirs was flagged (check measurements are mono-plotted, not adjusted: only a check point
    that is also measured in the adjustment can be); ``checks_gross``: check measurements whose
    own error is gross (:func:`._snooping.gross_checks`), ``{id, image, e_m, n_m}``, their points
    left out of the statistics too.
    """

    flagged: list[dict]
    rounds: dict
    line_offsets: list[dict]
    checks_excluded: tuple[str, ...] = ()
    loss: str = "l2"
    checks_gross: tuple[dict, ...] = ()

    @property
    def checks_out(self) -> set[str]:
        """Every check point left out of the statistics."""
        return set(self.checks_excluded) | {c["id"] for c in self.checks_gross}

    @property
    def n_removed(self) -> int:
        return sum(1 for f in self.flagged if f["removed"])

    @classmethod
    def collect(
        cls,
        level1,
        l2,
        rows: dict,
        strip,
        line_offsets: list[dict],
        solver,
        tie_ids=(),
        check_error_m: np.ndarray | None = None,
    ) -> GrossErrors:
        """From the level-1 :class:`~jaxgeo.bundle.AdjustResult`, the level-2
        :class:`~._snooping.Level2Snooping`, the ``solver`` (its loss and ``blunder_k``), the
        ids of the ties (formed and measured: their height priors are "tie height") and the
        check measurements' final errors ``(c, 2)`` m (rows ``rows["check"]``)."""
        flagged = []
        removed = level1.removed if level1.removed is not None else np.zeros(0, bool)
        for i in np.flatnonzero(level1.blunders):
            w = np.abs(np.nan_to_num(level1.standardized[i]))
            flagged.append({"level": 1, "image": level1.observation_images[i],
                            "id": level1.observation_ids[i], "what": "image",
                            "w": float(w.max()), "removed": bool(removed[i])})  # fmt: skip
        ties = set(tie_ids)
        for p, w in zip(level1.gcp_flagged, level1.gcp_w, strict=True):
            what = "tie height" if p in ties else "ground"  # a tie removed with its height prior
            flagged.append({"level": 1, "image": None, "id": p, "what": what, "w": float(w),
                            "removed": p in level1.gcp_removed})  # fmt: skip
        o = strip.observations
        new = l2.removed & ~l2.removed_level1
        for j in np.flatnonzero(new | ((l2.w > solver.blunder_k) & ~l2.removed_level1)):
            i = rows["gcp"][j]
            flagged.append({"level": 2, "image": o.images[i], "id": o.point_ids[i],
                            "what": "image", "w": float(l2.w[j]),
                            "removed": bool(new[j])})  # fmt: skip
        bad = {f["id"] for f in flagged}
        role = dict(zip(strip.ground.ids, strip.ground.role, strict=True))
        checks = tuple(sorted(p for p in bad if role.get(p) == "check"))
        gross_chk = []
        if check_error_m is not None:
            err = np.asarray(check_error_m)
            scene = np.array([strip.scene_index(o.images[i]) for i in rows["check"]], dtype=int)
            for j in np.flatnonzero(gross_checks(scene, err)):
                i = rows["check"][j]
                gross_chk.append({"id": o.point_ids[i], "image": o.images[i],
                                  "e_m": float(err[j, 0]), "n_m": float(err[j, 1])})  # fmt: skip
        return cls(flagged, {"level1": int(level1.snooping_rounds), "level2": int(l2.rounds)},
                   list(line_offsets), checks, solver.loss, tuple(gross_chk))  # fmt: skip

    def to_dict(self) -> dict:
        return {
            "loss": self.loss,
            "n_flagged": len(self.flagged),
            "n_removed": self.n_removed,
            "flagged": self.flagged,
            "snooping_rounds": self.rounds,
            "line_offsets": self.line_offsets,
            "checks_excluded": list(self.checks_excluded),
            "checks_gross": list(self.checks_gross),
        }

    def format(self) -> str:
        """Plain-text lines: the flagged observations (worst first), the broken seams."""
        lines = []
        if self.flagged:
            gone = self.n_removed
            lines.append(
                f"gross errors: {len(self.flagged)} observations flagged (|w| > k), {gone} removed "
                f"and re-solved (rounds: level 1 {self.rounds['level1']}, level 2 "
                f"{self.rounds['level2']}):"
            )
            for f in sorted(self.flagged, key=lambda f: -f["w"]):
                where = f"@{f['image']}" if f["image"] else f" ({f['what']})"
                how = "removed" if f["removed"] else "flagged only"
                lines.append(f"  level {f['level']}: {f['id']}{where}  w = {f['w']:.1f}  {how}")
        else:
            lines.append("gross errors: none flagged")
        if self.checks_excluded:
            lines.append(f"check points excluded from the statistics (an observation flagged): "
                         f"{len(self.checks_excluded)}")  # fmt: skip
        if self.checks_gross:
            lines.append(
                f"check measurements with a gross error of their own (error > {CHECK_K:g} robust "
                f"sigmas from their sub-scene's other checks), their points excluded from the "
                f"statistics: "
                + ", ".join(
                    f"{c['id']}@{c['image']} (E {c['e_m']:+.2f} N {c['n_m']:+.2f} m)"
                    for c in self.checks_gross[:20]
                )  # fmt: skip
                + (" ..." if len(self.checks_gross) > 20 else "")
            )
        if self.line_offsets:
            lines.append(line_offset_message(self.line_offsets))
        return "\n".join(lines)


def line_offset_message(suspects: list[dict]) -> str:
    """The broken seams (:func:`._snooping.suspect_offsets`) in words, one sentence per
    sub-scene named (or per seam where every sub-scene after it is shifted)."""
    parts, done = [], set()
    for s in suspects:
        seam = (f"{s['a']} | {s['b']}: {s['col_px']:+.1f} px (columns), {s['row_px']:+.1f} px "
                "(rows)")  # fmt: skip
        if s["scene"] is None:
            parts.append(
                f"the vendor RPCs disagree at the formed ties of {seam} beyond the strip's other "
                "seams: the line offsets (first_line) of every sub-scene from there on look "
                "shifted alike"
            )
            continue
        if s["scene"] in done:
            continue
        done.add(s["scene"])
        own = [x for x in suspects if x["scene"] == s["scene"]]
        lines = np.mean([x["row_px"] if x["b"] == s["scene"] else -x["row_px"] for x in own])
        seams = "; ".join(
            f"{x['a']} | {x['b']}: {x['col_px']:+.1f} px (columns), {x['row_px']:+.1f} px (rows)"
            for x in own
        )
        parts.append(
            f"the line offset (first_line) of {s['scene']} is probably wrong by {lines:+.0f} "
            f"lines (too {'large' if lines > 0 else 'small'}): the vendor RPCs disagree at its "
            f"formed ties ({seams}) beyond the strip's other seams; its bias absorbs the shift, "
            "which no residual shows (its check points are off); correct its first_line"
        )
    return ". ".join(parts)


def _rms(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def _max(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.max(np.abs(x))) if x.size else float("nan")


@dataclasses.dataclass(frozen=True)
class StripReport:
    """``scenes``: per sub-scene ``{name, gcp, n_check, <stage>: {e, n, plan}}`` RMS metres;
    ``pairs``: per adjacent pair ``{a, b, n_ties, <stage>: {rms, max}}`` tie gaps in metres;
    ``strip``: whole-strip figures (the same over all check points / ties, level-1 s0, steps)."""

    scenes: list[dict]
    pairs: list[dict]
    strip: dict
    rows: dict = dataclasses.field(repr=False, default_factory=dict)
    gross: GrossErrors | None = dataclasses.field(repr=False, default=None)

    def to_dict(self) -> dict:
        return {"strip": self.strip, "scenes": self.scenes, "pairs": self.pairs}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, allow_nan=True)

    def format(self) -> str:
        """Plain-text tables: sub-scenes, then pairs, then the whole strip."""
        lines = [
            "sub-scene        GCP  checks   check RMS E/N (m): direct      level 1      level 2",
        ]
        for r in self.scenes:
            cells = "".join(f"  {r[s]['e']:6.2f}/{r[s]['n']:<6.2f}" for s in STAGES)
            gcp = "yes" if r["gcp"] else " - "
            lines.append(f"{r['name']:<16} {gcp}  {r['n_check']:6d} {cells}")
        lines.append("")
        lines.append("pair                            ties   tie gap RMS/max (m): direct    level 1"
                     "      level 2")  # fmt: skip
        for p in self.pairs:
            cells = "".join(f"  {p[s]['rms']:6.3f}/{p[s]['max']:<6.3f}" for s in STAGES)
            lines.append(f"{p['a'] + ' | ' + p['b']:<31} {p['n_ties']:5d} {cells}")
        s = self.strip
        lines.append("")
        n_out = s.get("n_check_excluded", 0)
        excl = f", {n_out} excluded as gross errors" if n_out else ""
        for st in STAGES:
            c, g = s["check_rms_m"][st], s["tie_gap_m"][st]
            lines.append(
                f"whole strip, {st:<7}: check RMS E {c['e']:.2f} N {c['n']:.2f} plan "
                f"{c['plan']:.2f} m ({s['n_check']} checks{excl}); tie gap RMS {g['rms']:.3f} max "
                f"{g['max']:.3f} m ({s['n_ties']} ties)"
            )
        lines.append("heights: not evaluated (one view direction per point: checks are "
                     "mono-plotted at their surveyed heights)")  # fmt: skip
        if s.get("n_measured_ties"):
            lines.append(f"level 1 also adjusted {s['n_measured_ties']} measured tie points")
        lines.append(
            f"level 1: {s['scenes']} sub-scenes, {s['unknowns']} unknowns, s0 {s['s0']:.3f}, "
            f"{s['steps']} steps, {'converged' if s['converged'] else 'NOT CONVERGED'}; "
            f"level 2: {s['degree']} correction from {s['n_gcp']} GCP measurements, residual "
            f"RMS E {s['gcp_rms_level2_m']['e']:.2f} N {s['gcp_rms_level2_m']['n']:.2f} m"
        )
        cv = s["leave_one_scene_out_rms_m"]
        lines.append(
            "level 2, GCP scenes left out in turn, RMS (m): "
            + ", ".join(f"{d} {v:.2f}" for d, v in cv.items())
        )
        if self.gross is not None:
            lines.append(self.gross.format())
        return "\n".join(lines)


def scene_rows(
    names: Sequence[str],
    gcp_scenes: Sequence[int],
    check_scene: np.ndarray,
    errors: Mapping[str, np.ndarray],
) -> list[dict]:
    """Per sub-scene check RMS for each stage's ``(c, 2)`` east/north errors."""
    out = []
    gcp = set(int(k) for k in gcp_scenes)
    for k, name in enumerate(names):
        sel = check_scene == k
        row = {"name": name, "gcp": k in gcp, "n_check": int(sel.sum())}
        for st, err in errors.items():
            e = err[sel]
            row[st] = {"e": _rms(e[:, 0]), "n": _rms(e[:, 1]), "plan": _rms(np.hypot(*e.T))}
        out.append(row)
    return out


def pair_rows(
    names: Sequence[str], tie_pair: np.ndarray, gaps: Mapping[str, np.ndarray]
) -> list[dict]:
    """Per adjacent pair tie-gap RMS / max (m) for each stage's ``(t, 2)`` gaps."""
    out = []
    for k in range(len(names) - 1):
        sel = tie_pair == k
        row = {"a": names[k], "b": names[k + 1], "n_ties": int(sel.sum())}
        for st, gap in gaps.items():
            d = np.hypot(*gap[sel].T) if sel.any() else np.zeros(0)
            row[st] = {"rms": _rms(d), "max": _max(d)}
        out.append(row)
    return out


def whole(errors: Mapping[str, np.ndarray], gaps: Mapping[str, np.ndarray]) -> dict:
    """Whole-strip check RMS and tie gaps per stage."""
    return {
        "check_rms_m": {
            st: {"e": _rms(e[:, 0]), "n": _rms(e[:, 1]), "plan": _rms(np.hypot(*e.T))}
            for st, e in errors.items()
        },
        "tie_gap_m": {
            st: {"rms": _rms(np.hypot(*g.T)), "max": _max(np.hypot(*g.T))} for st, g in gaps.items()
        },
    }


def strip_report(
    strip, sol, ev, rows: dict, inp, unknowns: int, degree: str, gross: GrossErrors | None = None
) -> StripReport:
    """The :class:`StripReport` of a :func:`~._solve.two_level` solution ``sol``; ``rows``:
    the strip's observation rows of the GCP and check measurements (``{"gcp": [...], ...}``);
    ``gross``: the gross errors found (check points in ``gross.checks_out`` are left out of
    the check statistics; ``n_check_excluded`` says how many measurements)."""
    o = strip.observations
    out = gross.checks_out if gross is not None else set()
    use = np.array([o.point_ids[i] not in out for i in rows["check"]], dtype=bool)
    check_rows = [i for i, u in zip(rows["check"], use, strict=True) if u]
    check_scene = np.array([strip.scene_index(o.images[i]) for i in check_rows], dtype=int)
    errors = {
        "direct": np.asarray(ev.check_error_before_m)[use],
        "level1": np.asarray(ev.check_error_level1_m)[use],
        "level2": np.asarray(ev.check_error_level2_m)[use],
    }
    gaps = {
        "direct": np.asarray(ev.tie_gap_before_m),
        "level1": np.asarray(ev.tie_gap_level1_m),
        "level2": np.asarray(ev.tie_gap_level2_m),
    }
    gcp_scenes = sorted({strip.scene_index(o.images[i]) for i in rows["gcp"]})
    g2 = np.asarray(sol.gcp_error_level2_m)
    s = sol.level1
    info = {
        "scenes": len(strip.names),
        "unknowns": int(unknowns),
        "degree": degree,
        "n_check": int(len(errors["level1"])),
        "n_ties": int(inp.ties.n_ties),
        "n_measured_ties": len(inp.measured_ids),
        "n_gcp": int(len(g2)),
        "n_check_excluded": int(np.sum(~use)),
        "gcp_scenes": [strip.names[k] for k in gcp_scenes],
        "s0": float(s.s0),
        "steps": int(s.num_steps),
        "converged": bool(s.result == RESULTS.successful),
        "gcp_rms_level2_m": {"e": _rms(g2[:, 0]), "n": _rms(g2[:, 1])},
        "leave_one_scene_out_rms_m": dict(
            zip(N_TERMS, map(float, np.asarray(sol.cv_rms_m)), strict=True)
        ),
        **whole(errors, gaps),
        "gross_errors": gross.to_dict() if gross is not None else None,
    }
    return StripReport(
        scene_rows(strip.names, gcp_scenes, check_scene, errors),
        pair_rows(strip.names, inp.ties.pair, gaps),
        info,
        rows,
        gross,
    )
