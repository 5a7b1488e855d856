"""Does a DSM made with jitter-corrected models lose its corrugation? (issue 28, item 1).

A simulated Pleiades-like pair with a sinusoidal attitude jitter (``jaxgeo simulate
stereo-scene --jitter-px A --jitter-period-lines P --exact-rpc``: RPCs fitted exactly to the
jitter-free models) is adjusted from its verified SIFT ties alone
(:func:`jaxgeo.stereo.tie_points`, no GCP) as :mod:`benchmarks.accuracy.jitter` does: RPC +
:class:`~jaxgeo.models.AffineBias`, and RPC + :class:`~jaxgeo.models.JitterBias` (knots every
``--knot-lines``, smoothness ``--smoothness-px``), with the same priors. A DSM of the whole
left image is then made (:func:`jaxgeo.stereo.dsm_from_images`, intersection) with each set
of models: the delivered RPCs, the affine-adjusted ones, the jitter-adjusted ones, and the
true models (the scene's jitter on the exact RPCs: the chain's floor), on the grid of
``truth_dsm.tif``. Per DSM, of ``error = DSM - truth`` over the cells both have (interpolated
cells included):

- ``rmse_m``, ``median_m``, ``nmad_m``, ``le90_m`` (of ``|error - median|``), ``cells``;
  the same in ``interior``, over the cells whose true ground point projects into the left
  image (its delivered RPC) at least ``--edge-lines`` from its first and last lines (the
  DSM's edges, tens of metres wrong with every model, would otherwise swamp the line bins);
- in ``interior``, the corrugation, the jitter's signature, an error that varies with the
  image line: the cells binned by that line (``--bin-lines`` per bin); ``line_rms_m`` the RMS
  of the per-bin mean errors, ``line_std_m`` their standard deviation (the overall offset
  removed), ``period_amplitude_m`` the amplitude of a sinusoid of the jitter's period fitted
  to them;
- the tie residual across the epipolar direction after each adjustment (as in ``jitter``).

Can height information remove what the ties alone leave (the along-track jitter looks like a
height change to them)? Two more cases, ``jitter_dem_<name>``: the same jitter adjustment with
every tie's height from a DEM as an observation (:func:`jaxgeo.bundle.adjust`'s
``tie_height``, ``tie_height_sigma_m``). Both DEMs are made from ``truth_dsm.tif`` (its voids
filled with the nearest height, 2 cells of margin), block-averaged to ``--srtm-res-m`` (sigma
``--srtm-sigma-m``: SRTM-like) and ``--lidar-res-m`` (sigma ``--lidar-sigma-m``: lidar-like),
written as GeoTIFF and read with :func:`jaxgeo.io.read_dem` (ellipsoidal, as the truth). They
carry no error but their resolution's; a third, ``srtm_noisy``, is the SRTM-like one plus a
correlated error as a real SRTM has (a Gaussian random field of standard deviation
``--srtm-noise-m`` and correlation ``NOISE_CORRELATION_M``, one draw seeded by the scene's
seed; ``--srtm-noise-m 0``: no such case). ``dems.<name>.error_m`` is each DEM's error at the
scene's truth points. ``corrugation`` gathers, per DSM, the interior RMSE, median,
``line_std_m`` and ``period_amplitude_m``.

One JSON object on stdout (the machine last, :func:`benchmarks.harness.emit`) and, with
``--save``, in ``benchmarks/results/jitter_dsm-<size>px_seed<seed>-<machine>.json``::

    python -m benchmarks.accuracy.jitter_dsm --size 800 --seed 2841 --save
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import tempfile
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from benchmarks.accuracy.jitter import HEIGHT_MARGIN_M, across_rms, adjust_case  # noqa: E402
from benchmarks.harness import emit, result_name  # noqa: E402

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"
NOISE_CORRELATION_M = 90.0
"""Standard deviation (m on the ground) of the Gaussian kernel that correlates the noisy
SRTM-like DEM's error (a white field smoothed by it, then scaled)."""


def read_truth(directory):
    """``truth_dsm.tif``: heights (NaN: no data), the cell centres' map x, y, res, epsg and the
    upper-left corner."""
    import rasterio

    with rasterio.open(pathlib.Path(directory) / "truth_dsm.tif") as src:
        h = src.read(1).astype(np.float64)
        t = src.transform
        epsg = src.crs.to_epsg()
    rows, cols = h.shape
    xx, yy = np.meshgrid(t.c + t.a * (np.arange(cols) + 0.5), t.f + t.e * (np.arange(rows) + 0.5))
    return h, xx, yy, float(t.a), int(epsg), (float(t.c), float(t.f))


def cell_lines(rpc, xx, yy, h, epsg) -> np.ndarray:
    """The left image's line of each cell's true ground point (NaN where ``h`` is NaN)."""
    import pyproj

    lon, lat = pyproj.Transformer.from_crs(epsg, 4326, always_xy=True).transform(xx, yy)
    ok = np.isfinite(h)
    pts = np.stack([np.asarray(lon)[ok], np.asarray(lat)[ok], h[ok]], -1)
    out = np.full(h.shape, np.nan)
    out[ok] = np.asarray(rpc.project(pts))[:, 1]
    return out


def stats(e: np.ndarray) -> dict:
    """RMSE, mean, median, NMAD and LE90 (of ``|e - median|``) of the errors ``e`` (m)."""
    med = float(np.median(e))
    dev = np.abs(e - med)
    return {
        "cells": int(e.size),
        "rmse_m": float(np.sqrt(np.mean(e**2))),
        "mean_m": float(np.mean(e)),
        "median_m": med,
        "nmad_m": float(1.4826 * np.median(dev)),
        "le90_m": float(np.quantile(dev, 0.9)),
    }


def errors(dsm_h, truth_h, lines, size, args) -> dict:
    """Statistics of ``dsm_h - truth_h`` over every cell, and over the interior cells (those
    whose line is at least ``args.edge_lines`` inside the image) with their per-line-bin means
    (module docstring)."""
    e = dsm_h - truth_h
    ok = np.isfinite(e) & np.isfinite(lines)
    inner = ok & (lines >= args.edge_lines) & (lines <= size - 1 - args.edge_lines)
    out = stats(e[ok])
    y, e = lines[inner], e[inner]
    b = np.floor((y - args.edge_lines) / args.bin_lines).astype(int)
    ids, inv, counts = np.unique(b, return_inverse=True, return_counts=True)
    means = np.bincount(inv, weights=e) / counts
    keep = counts >= 20
    m = means[keep]
    w = 2 * np.pi * (args.edge_lines + (ids[keep] + 0.5) * args.bin_lines)
    w = w / args.jitter_period_lines
    design = np.stack([np.ones_like(w), np.sin(w), np.cos(w)], -1)
    coef = np.linalg.lstsq(design, m, rcond=None)[0]
    out["interior"] = stats(e) | {
        "line_bins": int(keep.sum()),
        "line_rms_m": float(np.sqrt(np.mean(m**2))),
        "line_std_m": float(np.std(m)),
        "period_amplitude_m": float(np.hypot(coef[1], coef[2])),
        "line_means_m": [round(float(v), 4) for v in m],
    }
    return out


def make_dem(truth, res_m: float, path, noise_m: float = 0.0, seed: int = 0) -> pathlib.Path:
    """A GeoTIFF DEM of the truth block-averaged to ``res_m`` (whole truth cells per block):
    the truth's voids filled with the nearest height first, then 2 cells of margin (edge
    heights) all round; plus, with ``noise_m``, a random field of that standard deviation
    correlated over ``NOISE_CORRELATION_M`` (drawn with ``seed``)."""
    import rasterio
    from rasterio.transform import Affine
    from scipy import ndimage

    h, _, _, res, epsg, (x0, y0) = truth
    void = ~np.isfinite(h)
    idx = ndimage.distance_transform_edt(void, return_distances=False, return_indices=True)
    filled = h[tuple(idx)]
    f = max(1, round(res_m / res))
    rows, cols = -(-filled.shape[0] // f), -(-filled.shape[1] // f)
    pad = ((0, rows * f - filled.shape[0]), (0, cols * f - filled.shape[1]))
    blocks = np.pad(filled, pad, mode="edge").reshape(rows, f, cols, f).mean(axis=(1, 3))
    margin = 2
    dem = np.pad(blocks, margin, mode="edge")
    cell = res * f
    if noise_m > 0:
        white = np.random.default_rng(seed).standard_normal(dem.shape)
        field = ndimage.gaussian_filter(white, NOISE_CORRELATION_M / cell, mode="wrap")
        dem = dem + field * (noise_m / field.std())
    dem = dem.astype(np.float32)
    transform = Affine(cell, 0.0, x0 - margin * cell, 0.0, -cell, y0 + margin * cell)
    profile = {"driver": "GTiff", "width": dem.shape[1], "height": dem.shape[0], "count": 1,
               "dtype": "float32", "crs": f"EPSG:{epsg}", "transform": transform}  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(dem, 1)
    return pathlib.Path(path)


def dems(truth, scene, args, folder) -> dict:
    """``name -> (DEM, sigma_m, description)`` for the SRTM-like, lidar-like and noisy
    SRTM-like DEMs."""
    from jaxgeo.io import read_dem

    out = {}
    todo = [("srtm", args.srtm_res_m, args.srtm_sigma_m, 0.0),
            ("lidar", args.lidar_res_m, args.lidar_sigma_m, 0.0)]  # fmt: skip
    if args.srtm_noise_m > 0:
        todo.append(("srtm_noisy", args.srtm_res_m, args.srtm_sigma_m, args.srtm_noise_m))
    for name, res_m, sigma, noise in todo:
        path = pathlib.Path(folder) / f"dem_{name}.tif"
        make_dem(truth, res_m, path, noise, int(scene.info["params"]["seed"]))
        dem = read_dem(path, height="ellipsoidal")
        e = dem(scene.points[:, :2]) - scene.points[:, 2]
        error = {("points" if k == "cells" else k): v for k, v in stats(e).items()}
        info = {"cell_m": round(truth[3] * max(1, round(res_m / truth[3])), 3), "sigma_m": sigma,
                "noise_m": noise, "shape": list(dem.shape), "error_m": error}  # fmt: skip
        out[name] = (dem, sigma, info)
    return out


def true_models(scene) -> dict:
    """The true jittered models, as fast as RPCs: each image's jitter
    (:class:`~jaxgeo.simulate._stereo_scene_models.JitteredModel`) on its exact RPC (the
    jitter-free model to ~1e-5 px) instead of on the physical model (whose DSM took over 10
    minutes at 800 px)."""
    from jaxgeo.simulate._stereo_scene_models import JitteredModel

    out = {}
    for n in ("left", "right"):
        t = scene.truth[n]
        out[n] = JitteredModel(scene.rpcs[n], t.amplitude_px, t.period_lines, t.phase_rad)
    return out


def dsm_case(models, directory, truth, h_range, lines, args) -> dict:
    """A DSM of the whole left image with ``models`` on the truth's grid, and its errors."""
    from jaxgeo.stereo import DSMSettings, dsm_from_images

    truth_h, _, _, res, epsg, origin = truth
    d = pathlib.Path(directory)
    t = time.perf_counter()
    dsm, stats = dsm_from_images(
        [models["left"], models["right"]], [d / "left.tif", d / "right.tif"],
        DSMSettings(res_m=res, epsg=epsg, heights=h_range, register=False), origin=origin,
        shape=truth_h.shape,
    )  # fmt: skip
    size = int(args.size)
    out = errors(np.asarray(dsm.height, np.float64), truth_h, lines, size, args)
    out["dsm_s"] = round(time.perf_counter() - t, 1)
    keep = ("vertical_disparity_px", "disparity_fill")
    out |= {k: stats[0][k] for k in keep if k in stats[0]}
    return out


def run(directory, args) -> dict:
    """The whole study on the scene in ``directory`` (module docstring)."""
    from jaxgeo.bundle import AdjustSettings
    from jaxgeo.io import open_image
    from jaxgeo.models import AffineBias, JitterBias
    from jaxgeo.simulate import read_stereo_scene
    from jaxgeo.stereo import MatchSettings, tie_points

    d = pathlib.Path(directory)
    scene = read_stereo_scene(d)
    h = scene.points[:, 2]
    h_range = (float(h.min()) - HEIGHT_MARGIN_M, float(h.max()) + HEIGHT_MARGIN_M)
    t = time.perf_counter()
    m1, m2 = (open_image(d / f"{n}.tif").model for n in ("left", "right"))
    ties = tie_points(
        m1, m2, d / "left.tif", d / "right.tif", MatchSettings(height_range_m=h_range)
    )
    t_ties = time.perf_counter() - t
    span = (0.0, float(scene.size - 1))
    kw = {"knot_lines": args.knot_lines, "smoothness_px": args.smoothness_px}
    affine, m_affine = adjust_case(scene, ties, lambda rpc: AffineBias(), h_range)
    jitter, m_jitter = adjust_case(scene, ties, lambda rpc: JitterBias(span, **kw), h_range)
    given = {n: scene.rpcs[n] for n in ("left", "right")}
    truth = read_truth(d)
    truth_h, xx, yy, _, epsg, _ = truth
    lines = cell_lines(scene.rpcs["left"], xx, yy, truth_h, epsg)
    cases = {"given": given, "affine": m_affine, "jitter": m_jitter}
    adjusted = {"affine": affine, "jitter": jitter}
    dem_info = {}
    with tempfile.TemporaryDirectory(prefix="jaxgeo_jitter_dsm_dem_") as folder:
        for name, (dem, sigma, info) in dems(truth, scene, args, folder).items():
            print(f"[jitter_dsm] adjustment with {name} heights", file=sys.stderr, flush=True)
            case = f"jitter_dem_{name}"
            dem_info[name] = info
            adjusted[case], cases[case] = adjust_case(
                scene, ties, lambda rpc: JitterBias(span, **kw), h_range,
                settings=AdjustSettings(tie_height=dem, tie_height_sigma_m=sigma),
            )  # fmt: skip
    if args.truth_models:
        cases["true_models"] = true_models(scene)
    dsms = {}
    for name, models in cases.items():
        print(f"[jitter_dsm] DSM with the {name} models", file=sys.stderr, flush=True)
        dsms[name] = dsm_case(models, d, truth, h_range, lines, args)
    a, j = dsms["affine"]["interior"], dsms["jitter"]["interior"]
    return {
        "n_ties": len(ties),
        "ties_s": round(t_ties, 1),
        "height_range_m": list(h_range),
        "knot_lines": args.knot_lines,
        "smoothness_px": args.smoothness_px,
        "bin_lines": args.bin_lines,
        "edge_lines": args.edge_lines,
        "adjust": {"given": {"ties": across_rms(given, ties.xy1, ties.xy2, h_range)}} | adjusted,
        "dems": dem_info,
        "dsm": dsms,
        "corrugation": {
            name: {
                k: round(v["interior"][k], 4)
                for k in ("rmse_m", "median_m", "line_std_m", "period_amplitude_m")
            }
            for name, v in dsms.items()
        },
        "interior_rmse_ratio_affine_over_jitter": round(a["rmse_m"] / j["rmse_m"], 3),
        "line_std_ratio_affine_over_jitter": round(a["line_std_m"] / j["line_std_m"], 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=800, help="image side (px)")
    parser.add_argument("--seed", type=int, default=2841)
    parser.add_argument("--jitter-px", type=float, default=1.5)
    parser.add_argument("--jitter-period-lines", type=float, default=400.0)
    parser.add_argument("--knot-lines", type=float, default=50.0)
    parser.add_argument("--smoothness-px", type=float, default=0.3)
    parser.add_argument("--bin-lines", type=float, default=20.0, help="lines per error bin")
    parser.add_argument("--edge-lines", type=float, default=40.0,
                        help="lines left out at the top and bottom of the line bins")  # fmt: skip
    parser.add_argument("--no-truth-models", dest="truth_models", action="store_false",
                        help="skip the DSM with the true models")  # fmt: skip
    parser.add_argument("--srtm-res-m", type=float, default=30.0, help="SRTM-like DEM cell")
    parser.add_argument("--srtm-sigma-m", type=float, default=5.0, help="its tie height sigma")
    parser.add_argument("--srtm-noise-m", type=float, default=3.0,
                        help="error of the noisy SRTM-like DEM (0: no such case)")  # fmt: skip
    parser.add_argument("--lidar-res-m", type=float, default=2.0, help="lidar-like DEM cell")
    parser.add_argument("--lidar-sigma-m", type=float, default=0.3, help="its tie height sigma")
    parser.add_argument("--scene", help="an existing stereo-scene folder (else simulated)")
    parser.add_argument("--save", action="store_true", help="also write benchmarks/results/")
    args = parser.parse_args()

    import jaxgeo
    from jaxgeo.io.internal import atomic_write_text
    from jaxgeo.simulate import StereoSceneSettings, stereo_scene

    t0 = time.perf_counter()
    directory = args.scene
    if directory is None:
        directory = tempfile.mkdtemp(prefix="jaxgeo_jitter_dsm_")
        stereo_scene(directory, args.size, args.seed, StereoSceneSettings(
            jitter_px=args.jitter_px, jitter_period_lines=args.jitter_period_lines,
            exact_rpc=True))  # fmt: skip
    t_sim = time.perf_counter() - t0
    params = json.loads(pathlib.Path(directory, "truth.json").read_text())["params"]
    args.jitter_period_lines = float(params["jitter_period_lines"])
    args.size = int(params["size"])
    out = {"benchmark": "jitter_dsm", "jaxgeo": jaxgeo.__version__, "scene": params,
           "simulate_s": round(t_sim, 1)}  # fmt: skip
    out |= run(directory, args)
    out["total_s"] = round(time.perf_counter() - t0, 1)
    result = emit(out, indent=1, default=float)
    if args.save:
        case = f"{params['size']}px_seed{params['seed']}"
        m = result["machine"]
        loaded = m["load_average"][0] > (m["cores_usable"] or m["cores"])  # others' work
        path = RESULTS / result_name("jitter_dsm", case, m, loaded=loaded)
        atomic_write_text(path, json.dumps(result, indent=1, default=float) + "\n", overwrite=True)
        print(f"saved {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
