"""Per sub-scene and whole-strip figures of the strip adjustment (003_ table 1 and figure 2).

Absolute: check points localised with each stage's model at their surveyed height (what an
ortho does) minus their surveyed position, east/north metres, RMS per sub-scene. Continuity:
for each adjacent pair, the ground distance between a tie localised in one sub-scene and in the
other at the tie's height -- zero for a seamless mosaic.

Stages: ``direct`` (vendor RPCs), ``level1`` (bundle-adjusted biases), ``level2`` (plus the
universal correction).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence

import numpy as np

from ..bundle.errors import RESULTS
from .universal import N_TERMS

STAGES = ("direct", "level1", "level2")


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
        for st in STAGES:
            c, g = s["check_rms_m"][st], s["tie_gap_m"][st]
            lines.append(
                f"whole strip, {st:<7}: check RMS E {c['e']:.2f} N {c['n']:.2f} plan "
                f"{c['plan']:.2f} m ({s['n_check']} checks); tie gap RMS {g['rms']:.3f} max "
                f"{g['max']:.3f} m ({s['n_ties']} ties)"
            )
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


def strip_report(strip, sol, ev, rows: dict, inp, unknowns: int, degree: str) -> StripReport:
    """The :class:`StripReport` of a :func:`~.solve.two_level` solution ``sol``; ``rows``:
    the strip's observation rows of the GCP and check measurements (``{"gcp": [...], ...}``)."""
    o = strip.observations
    check_scene = np.array([strip.scene_index(o.images[i]) for i in rows["check"]], dtype=int)
    errors = {
        "direct": np.asarray(ev.check_error_before_m),
        "level1": np.asarray(ev.check_error_level1_m),
        "level2": np.asarray(ev.check_error_level2_m),
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
        "n_gcp": int(len(g2)),
        "gcp_scenes": [strip.names[k] for k in gcp_scenes],
        "s0": float(s.s0),
        "steps": int(s.num_steps),
        "converged": bool(s.result == RESULTS.successful),
        "gcp_rms_level2_m": {"e": _rms(g2[:, 0]), "n": _rms(g2[:, 1])},
        "leave_one_scene_out_rms_m": dict(
            zip(N_TERMS, map(float, np.asarray(sol.cv_rms_m)), strict=True)
        ),
        **whole(errors, gaps),
    }
    return StripReport(
        scene_rows(strip.names, gcp_scenes, check_scene, errors),
        pair_rows(strip.names, inp.ties.pair, gaps),
        info,
        rows,
    )
