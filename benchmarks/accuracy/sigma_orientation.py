"""Is a DSM's ``height_sigma`` with ``--orientation`` from ``adjust --bias jitter`` calibrated?
(issue 53, item 5).

Per seed, the chain a user runs, through the CLI (``python -m jaxgeo.cli``): ``simulate
stereo-scene --size N --seed S --jitter-px 1.5`` (vendor RPCs: a few pixels of pointing error,
fitted without the jitter), ``match left.tif right.tif``, ``adjust --bias jitter`` (ties only, no
GCP, no DEM: the default priors of a relative orientation), then the DSM of the pair with the
adjusted models on the truth's grid (``--like truth_dsm.tif``) three ways:

- ``posterior``: ``make_dsm(orientation=orientation_covariances(...))``, the adjustment's
  posterior covariance of the bias shifts as it is written (what ``dsm --orientation`` used
  before this study);
- ``bounded``: ``jaxgeo dsm --orientation adjusted_models.json`` (the posterior bounded by the
  models' a priori where the ties leave a direction open:
  :func:`jaxgeo.stereo._uncertainty.adjusted_orientation`).

For each, over the cells with a height and a truth: the shares within 1 and 2 ``height_sigma``
of the truth (:func:`jaxgeo.stereo.sigma_calibration`; the goal 55-80 % / 85-99 %), the
median ratio |error| / sigma, RMSE, median sigma; per seed the DSM's median error (its
offset: the relative along-track orientation the ties cannot see) and NMAD, and the posterior
sigma of the relative shifts (x across, y along the epipolar direction). ``pooled``: all
seeds' cells together (each seed weighs its cells).

Why a scene is in or out: its DSM's offset is the vendor RPCs' relative along-track error
(the ties leave it open; the adjusted models keep the delivered ones' there). ``--sample A B``
measures that error on the scenes of seeds A..B-1 without rendering them
(:func:`jaxgeo.simulate._stereo_scene.stereo_scene_truth`: the mean over the truth points of
left minus right of RPC minus true image row), and the share of those scenes within 1 and 2
of the bounded sigma of the relative shift (``sqrt(2)`` times the a priori per image), the
calibration many scenes would give.

One JSON object on stdout (the machine last) and, with ``--save``, in
``benchmarks/results/sigma_orientation-<size>px_<n>seeds-<machine>.json``::

    python -m benchmarks.accuracy.sigma_orientation --size 400 --seeds 71 72 73 74 75 76 --save
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from benchmarks.harness import emit, result_name  # noqa: E402

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"
REPO = pathlib.Path(__file__).resolve().parents[2]
CASES = ("posterior", "bounded")


def jaxgeo_cli(*args: str) -> float:
    """Run ``jaxgeo ARGS --quiet`` (this tree's) in a process of its own; its seconds."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    t0 = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "jaxgeo.cli", *args, "--quiet"], env=env,
                         capture_output=True, text=True)  # fmt: skip
    if run.returncode != 0:
        raise RuntimeError(f"jaxgeo {' '.join(args)}: exit {run.returncode}\n{run.stderr}")
    return time.perf_counter() - t0


def read_band(path, name: str) -> np.ndarray:
    from jaxgeo.io.internal import open_raster

    with open_raster(path) as src:
        return src.read(list(src.descriptions).index(name) + 1).astype(np.float64)


def calibration(dsm, truth: np.ndarray) -> dict:
    from jaxgeo.stereo import sigma_calibration

    h, sigma = read_band(dsm, "height"), read_band(dsm, "height_sigma")
    cal = sigma_calibration(h, sigma, truth)
    err = (h - truth)[np.isfinite(h - truth) & np.isfinite(sigma)]
    med = float(np.median(err))
    return {**{k: round(v, 4) if isinstance(v, float) else v for k, v in cal.items()},
            "median_error_m": round(med, 3),
            "nmad_m": round(1.4826 * float(np.median(np.abs(err - med))), 3),
            "_ratio": np.abs(err) / sigma[np.isfinite(h - truth) & np.isfinite(sigma)]}  # fmt: skip


def relative_shift_sigmas(adjusted) -> dict:
    """Posterior sigmas (px) of the left - right bias shifts in x and y, and of their sums."""
    from jaxgeo.stereo._uncertainty import orientation_covariances

    cov = orientation_covariances(adjusted, ["left", "right"])
    out = {}
    for name, v in (("relative_x_px", [1, 0, -1, 0]), ("relative_y_px", [0, 1, 0, -1])):
        v = np.asarray(v, float)
        out[name] = round(float(np.sqrt(v @ cov @ v)), 4)
    return out


def one_seed(seed: int, size: int, folder: pathlib.Path) -> dict:
    from jaxgeo.io import open_image
    from jaxgeo.stereo import DSMSettings, make_dsm
    from jaxgeo.stereo._uncertainty import orientation_covariances
    from jaxgeo.tiles import TileSettings

    d = folder / f"seed{seed}"
    times = {}
    scene = ("--size", str(size), "--seed", str(seed), "--jitter-px", "1.5")
    times["simulate_s"] = jaxgeo_cli("simulate", "stereo-scene", *scene, "-o", str(d / "scene"))
    left, right = str(d / "scene" / "left.tif"), str(d / "scene" / "right.tif")
    truth_path = d / "scene" / "truth_dsm.tif"
    times["match_s"] = jaxgeo_cli("match", left, right, "-o", str(d / "ties.csv"))
    times["adjust_s"] = jaxgeo_cli("adjust", left, right, "--observations", str(d / "ties.csv"),
                                   "--bias", "jitter", "-o", str(d / "adj"))  # fmt: skip
    adjusted = d / "adj" / "adjusted_models.json"
    models = ["--model", f"left={adjusted}", "--model", f"right={adjusted}"]
    times["dsm_bounded_s"] = jaxgeo_cli("dsm", left, right, *models, "--orientation",
                                        str(adjusted), "--like", str(truth_path), "-o",
                                        str(d / "dsm_bounded.tif"))  # fmt: skip
    images = [open_image(p, model=adjusted) for p in (left, right)]
    settings = DSMSettings(like=str(truth_path))
    t0 = time.perf_counter()
    quiet = TileSettings(progress=False)
    make_dsm(images, d / "dsm_posterior.tif", settings, quiet,
             orientation=orientation_covariances(adjusted, ["left", "right"]))  # fmt: skip
    times["dsm_posterior_s"] = time.perf_counter() - t0
    truth = read_band(truth_path, read_truth_name(truth_path))
    out = {"seed": seed, **relative_shift_sigmas(adjusted)}
    for case in CASES:
        out[case] = calibration(d / f"dsm_{case}.tif", truth)
    out["seconds"] = {k: round(v, 1) for k, v in times.items()}
    return out


def read_truth_name(path) -> str:
    """The truth DSM's one band (no description): its name for :func:`read_band`."""
    from jaxgeo.io.internal import open_raster

    with open_raster(path) as src:
        return list(src.descriptions)[0]


def offset_sample(first: int, stop: int, size: int) -> dict:
    """The vendor RPCs' relative along-track error (px) of the scenes of seeds ``first`` ..
    ``stop - 1`` (module docstring), and the shares within 1 and 2 bounded sigmas."""
    from jaxgeo.simulate import StereoSceneSettings
    from jaxgeo.simulate._stereo_scene import stereo_scene_truth
    from jaxgeo.stereo._uncertainty import A_PRIORI_SHIFT_PX

    rel = []
    for seed in range(first, stop):
        scene = stereo_scene_truth(size, seed, StereoSceneSettings(jitter_px=1.5))
        pts = np.asarray(scene.points)
        err = {n: np.asarray(scene.rpcs[n].project(pts))[:, 1] - np.asarray(scene.xy[n])[:, 1]
               for n in ("left", "right")}  # fmt: skip
        rel.append(float(np.mean(err["left"] - err["right"])))
    rel = np.asarray(rel)
    sigma = np.sqrt(2.0) * A_PRIORI_SHIFT_PX
    return {"seeds": [first, stop - 1], "relative_y_px": [round(v, 3) for v in rel],
            "rms_px": round(float(np.sqrt(np.mean(rel**2))), 3),
            "bounded_relative_sigma_px": round(sigma, 3),
            "within_1_sigma": round(float(np.mean(np.abs(rel) <= sigma)), 3),
            "within_2_sigma": round(float(np.mean(np.abs(rel) <= 2 * sigma)), 3)}  # fmt: skip


def pooled(per_seed: list[dict], case: str) -> dict:
    ratio = np.concatenate([s[case].pop("_ratio") for s in per_seed])
    return {"n_cells": int(ratio.size), "within_1_sigma": round(float(np.mean(ratio <= 1)), 4),
            "within_2_sigma": round(float(np.mean(ratio <= 2)), 4),
            "median_ratio": round(float(np.median(ratio)), 4),
            "seeds_within_1_sigma_median": int(sum(s[case]["median_ratio"] <= 1
                                                   for s in per_seed))}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=400, help="image side (px)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[71, 72, 73, 74, 75, 76, 77, 78])
    parser.add_argument("--sample", type=int, nargs=2, metavar=("A", "B"),
                        help="also the relative error of the scenes of seeds A..B-1")  # fmt: skip
    parser.add_argument("--keep", help="a folder for the scenes and products (else temporary)")
    parser.add_argument("--save", action="store_true", help="also write benchmarks/results/")
    args = parser.parse_args()

    import jaxgeo
    from jaxgeo.io.internal import atomic_write_text

    t0 = time.perf_counter()
    folder = pathlib.Path(args.keep or tempfile.mkdtemp(prefix="jaxgeo_sigma_orientation_"))
    per_seed = []
    for seed in args.seeds:
        per_seed.append(one_seed(seed, args.size, folder))
        s = per_seed[-1]
        print(f"seed {seed}: offset {s['bounded']['median_error_m']:+.2f} m, within 1/2 sigma "
              f"posterior {s['posterior']['within_1_sigma']:.3f}/"
              f"{s['posterior']['within_2_sigma']:.3f}, bounded "
              f"{s['bounded']['within_1_sigma']:.3f}/{s['bounded']['within_2_sigma']:.3f}",
              file=sys.stderr, flush=True)  # fmt: skip
    out = {"benchmark": "sigma_orientation", "jaxgeo": jaxgeo.__version__, "size": args.size,
           "jitter_px": 1.5, "goal": {"within_1_sigma": [0.55, 0.80],
                                      "within_2_sigma": [0.85, 0.99]}}  # fmt: skip
    out["pooled"] = {case: pooled(per_seed, case) for case in CASES}
    out["seeds"] = per_seed
    if args.sample:
        out["offset_sample"] = offset_sample(*args.sample, args.size)
    out["total_s"] = round(time.perf_counter() - t0, 1)
    result = emit(out, indent=1, default=float)
    if args.save:
        case = f"{args.size}px_{len(args.seeds)}seeds"
        m = result["machine"]
        loaded = m["load_average"][0] > (m["cores_usable"] or m["cores"])  # others' work
        path = RESULTS / result_name("sigma_orientation", case, m, loaded=loaded)
        atomic_write_text(path, json.dumps(result, indent=1, default=float) + "\n", overwrite=True)
        print(f"saved {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
