"""``jaxgeo adjust`` at scale: a pair with 100 000 tie points, end to end through the CLI.

The case of issue 11 ("scale on real ties"), simulated (:mod:`jaxgeo.simulate._tiepair`): the
demo Cartosat-1 RPC pair, a small relative affine bias between the two images, 100 000 tie
points measured in both (1 % of the measurements with gross errors of 8-60 px), 12 GCPs measured
in ``fore`` only; affine bias with priors. Each loss runs ``jaxgeo adjust ... --json --out``
as a subprocess (start-up and compilation included) and is measured: wall time, peak RSS of
that process (``os.wait4``), LM steps, convergence, the mean tie residual per image and axis
(observations not flagged), and the recall of the gross errors (flagged / simulated) with the
number of clean observations flagged. One JSON object on stdout (the machine last:
:func:`benchmarks.harness.emit`)::

    python -m benchmarks.speed.adjust_scale [--ties 100000] [--loss l2 huber cauchy]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import numpy as np

from benchmarks.harness import emit

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def run_cli(args: list[str], log: pathlib.Path, env: dict) -> tuple[int, float, float, str]:
    """``(exit status, wall s, peak RSS MiB, stdout)`` of ``python -m jaxgeo.cli args``."""
    t0 = time.perf_counter()
    with open(log, "w") as out, open(log.with_suffix(".err"), "w") as err:
        cmd = [sys.executable, "-m", "jaxgeo.cli", *args]
        p = subprocess.Popen(cmd, stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    return p.returncode, wall, usage.ru_maxrss / 1024.0, log.read_text()


def tie_stats(residuals: pathlib.Path, gross: np.ndarray, detectable: np.ndarray) -> dict:
    """Mean tie residuals (px, per image and axis, unflagged) and gross-error recall (of all,
    and of those whose component across the epipolar direction is detectable)."""
    with open(residuals) as f:
        rows = list(csv.DictReader(f))
    flagged = np.array([r["blunder"] == "1" for r in rows])
    tie = np.array([r["id"].startswith("T") for r in rows])
    v = np.array([[float(r["vx_px"]), float(r["vy_px"])] for r in rows])
    img = np.array([r["image"] for r in rows])
    means = {
        name: np.round(np.mean(v[tie & ~flagged & (img == name)], axis=0), 5).tolist()
        for name in dict.fromkeys(img)
    }
    return {
        "tie_residual_mean_px": means,
        "max_abs_tie_mean_px": float(max(np.max(np.abs(m)) for m in means.values())),
        "flagged": int(flagged.sum()),
        "gross": int(gross.sum()),
        "recall": float(np.sum(flagged & gross) / max(gross.sum(), 1)),
        "detectable": int(detectable.sum()),
        "recall_detectable": float(np.sum(flagged & detectable) / max(detectable.sum(), 1)),
        "clean_flagged": int(np.sum(flagged & ~gross)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ties", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--loss", nargs="+", default=["l2", "huber", "cauchy"])
    parser.add_argument(
        "--detect-px",
        type=float,
        default=3.0,
        help="a gross error is detectable when its component across the epipolar direction "
        "exceeds this (px; along it, it moves the tie point's height)",
    )
    parser.add_argument("--prior-shift-px", type=float, default=5.0)
    parser.add_argument("--prior-matrix", type=float, default=1e-3)
    parser.add_argument("--keep", metavar="DIR", help="build the case here and keep it")
    parser.add_argument(
        "--warm-cache",
        action="store_true",
        help="use the user's compilation cache (default: a fresh one, compilation included)",
    )
    opts = parser.parse_args()

    from jaxgeo.simulate._tiepair import tie_pair

    t0 = time.perf_counter()
    pair = tie_pair(opts.ties, opts.seed)
    tmp = tempfile.TemporaryDirectory() if opts.keep is None else None
    root = pathlib.Path(opts.keep or tmp.name)
    files = pair.save(root / "case")
    detectable = pair.detectable(opts.detect_px)
    env = dict(os.environ)
    if not opts.warm_cache:
        env["JAXGEO_CACHE_DIR"] = str(root / "jax_cache")
    build_s = time.perf_counter() - t0
    out = {
        "case": {
            "ties": opts.ties,
            "observations": len(pair.observations),
            "gcps": len(pair.ground),
            "gross": int(pair.gross.sum()),
            "detectable": int(detectable.sum()),
            "fresh_compilation_cache": not opts.warm_cache,
            "build_s": round(build_s, 2),
        },
        "runs": {},
    }
    common = [
        "adjust", "--image", f"fore={files['fore']}", "--image", f"aft={files['aft']}",
        "--ground", str(files["ground"]), "--observations", str(files["observations"]),
        "--bias", "affine", "--bias-prior-shift-px", str(opts.prior_shift_px),
        "--bias-prior-matrix", str(opts.prior_matrix), "--json",
    ]  # fmt: skip
    for loss in opts.loss:
        dest = root / f"out_{loss}"
        rc, wall, rss, stdout = run_cli(
            [*common, "--loss", loss, "--out", str(dest)], root / f"{loss}.log", env
        )
        entry = {"exit": rc, "wall_s": round(wall, 2), "peak_rss_mib": round(rss, 1)}
        try:
            data = json.loads(stdout)
        except json.JSONDecodeError:
            entry["stderr_tail"] = (root / f"{loss}.err").read_text()[-2000:]
            out["runs"][loss] = entry
            continue
        entry.update(
            converged=data["converged"],
            message=data["message"],
            steps=data["num_steps"],
            s0=data["s0"],
            snooping_rounds=data["snooping_rounds"],
            removed=data["removed"],
            aft_bias={k: round(v, 7) for k, v in data["images"]["aft"]["params"].items()},
        )
        if (dest / "residuals.csv").exists():
            entry.update(tie_stats(dest / "residuals.csv", pair.gross, detectable))
        out["runs"][loss] = entry
    emit(out)
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
