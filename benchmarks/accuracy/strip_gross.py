"""Gross errors in a strip (issue 11): default robust strip adjustment vs least squares.

A simulated Carto-2S strip (``--scenes`` sub-scenes, GCPs in every ``--gcp-every``-th one and
the last, ``--ties`` formed ties per pair) is adjusted clean and with ``--fraction`` of its GCP
measurements and of its formed ties (one ray each) moved by 10-100 px, with least squares and
no snooping (the strip's old default) and with the default (Cauchy IRLS + data snooping at both
levels); then with one sub-scene's line offset wrong by ``--offset-px`` lines (one without GCPs
and one with). Reports the check-point RMS (plan, m) of the vendor RPCs and after level 2, the
flags' recall and precision (ties per tie point, GCP measurements per (point, sub-scene)), and
warm solve times (the second run of each configuration: compilation excluded).

    python -m benchmarks.accuracy.strip_gross [--scenes 12] [--ties 20] [--gcp-every 4] [--seed 7]

prints one JSON object on stdout (the machine last: :func:`benchmarks.harness.emit`; progress on
stderr).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
import warnings

import numpy as np

from benchmarks.harness import emit


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=12)
    ap.add_argument("--ties", type=int, default=20)
    ap.add_argument("--gcp-every", type=int, default=4)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--fraction", type=float, default=0.1)
    ap.add_argument("--offset-px", type=int, default=200)
    args = ap.parse_args()

    import jax

    jax.config.update("jax_enable_x64", True)
    import jaxgeo.strip._adjustment as strip_adjustment
    from jaxgeo.io import Observations
    from jaxgeo.simulate import Carto2SStripSettings, carto2s_strip
    from jaxgeo.simulate._gross import flag_scores
    from jaxgeo.strip import Strip, StripConfig, TieConfig, adjust_strip
    from jaxgeo.strip._config import STRIP_SOLVER
    from jaxgeo.strip._level1 import level1_input

    warnings.simplefilter("ignore")
    sim = carto2s_strip(args.scenes, seed=args.seed,
                        settings=Carto2SStripSettings(gcp_every=args.gcp_every))  # fmt: skip
    strip = Strip.from_simulation(sim)
    solvers = {
        "least_squares": dataclasses.replace(STRIP_SOLVER, loss="l2", remove_blunders=False),
        "default": STRIP_SOLVER,
    }

    def errors(rng, n):
        a, s = rng.uniform(0, 2 * np.pi, n), rng.uniform(10, 100, n)
        return np.stack([np.cos(a), np.sin(a)], -1) * s[:, None]

    rng = np.random.default_rng(args.seed)
    o = strip.observations
    role = dict(zip(strip.ground.ids, strip.ground.role, strict=True))
    rows = [i for i, p in enumerate(o.point_ids) if role[p] == "gcp"]
    pick = rng.choice(rows, max(2, round(args.fraction * len(rows))), replace=False)
    xy = o.xy.copy()
    xy[pick] += errors(rng, len(pick))
    bad_obs = {(o.point_ids[i], o.images[i]) for i in pick}
    gross = dataclasses.replace(strip, observations=Observations(o.point_ids, o.images, xy,
                                                                 o.sigma_px))  # fmt: skip
    bad_ties: set = set()
    tie_rng = np.random.default_rng(args.seed + 1)

    def corrupted(s, config=None, use_gcps=True):
        inp = level1_input(s, config, use_gcps)
        t = inp.ties
        chosen = np.random.default_rng(args.seed + 1).choice(
            t.n_ties, round(args.fraction * t.n_ties), replace=False
        )
        r = [
            np.flatnonzero(t.point == p)[k]
            for p, k in zip(chosen, tie_rng.integers(0, 2, len(chosen)), strict=True)
        ]  # noqa: E501
        q = np.array(inp.observations.xy)
        q[r] += errors(np.random.default_rng(args.seed + 2), len(r))
        bad_ties.update(inp.tie_ids[p] for p in chosen)
        ob = inp.observations
        return dataclasses.replace(
            inp, observations=Observations(ob.point_ids, ob.images, q, ob.sigma_px)
        )

    def run(s, solver, corrupt=False):
        config = StripConfig(ties=TieConfig(per_pair=args.ties), solver=solver)
        if corrupt:
            strip_adjustment.level1_input = corrupted
        try:
            adjust_strip(s, config)  # compile
            t = time.perf_counter()
            res = adjust_strip(s, config)
            dt = time.perf_counter() - t
        finally:
            strip_adjustment.level1_input = level1_input
        st = res.report.strip
        out = {
            "check_rms_plan_m": {k: st["check_rms_m"][k]["plan"] for k in ("direct", "level2")},
            "solve_s": dt,
            "n_flagged": len(res.gross_errors.flagged),
            "n_removed": res.gross_errors.n_removed,
            "rounds": res.gross_errors.rounds,
        }
        return res, out

    def scores(res):
        sc = flag_scores(res.gross_errors.flagged, bad_obs, bad_ties)
        return {"recall": sc.recall, "precision": sc.precision}

    out = {"args": vars(args)}
    for name, solver in solvers.items():
        print(f"{name}: clean", file=sys.stderr)
        _, out[f"clean_{name}"] = run(strip, solver)
        print(f"{name}: gross", file=sys.stderr)
        res, out[f"gross_{name}"] = run(gross, solver, corrupt=True)
        out[f"gross_{name}"].update(scores(res))
    out["corrupted"] = {"gcp_measurements": len(bad_obs), "ties": len(bad_ties)}
    gcp_scenes = set(strip.gcp_scenes())
    no_gcp = next(k for k in range(1, args.scenes) if k not in gcp_scenes)
    with_gcp = next(k for k in range(1, args.scenes) if k in gcp_scenes)
    for label, k in (("no_gcps", no_gcp), ("with_gcps", with_gcp)):
        scenes = list(strip.scenes)
        scenes[k] = dataclasses.replace(
            scenes[k], line_offset=scenes[k].line_offset + args.offset_px
        )
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res, info = run(dataclasses.replace(strip, scenes=tuple(scenes)), STRIP_SOLVER)
        info["scene"] = strip.names[k]
        info["named"] = [x["scene"] for x in res.gross_errors.line_offsets]
        info["warnings"] = sorted({w.category.__name__ for w in caught})
        info["flagged_scenes"] = sorted({f["image"] or "" for f in res.gross_errors.flagged})
        out[f"line_offset_{label}"] = info
    emit(out)


if __name__ == "__main__":
    main()
