"""RPC localisation speed: ``rpc.localize(xy, h)`` as README writes it, against GDAL, shareloc and
rpcm (when installed: ``benchmarks/peers/rpc.py``), same run.

    python -m benchmarks.speed.localization [--sizes 1e4 1e6] [--repeats 3]

Timing (:mod:`benchmarks.harness`): best of ``repeats`` calls after a warm-up (GDAL
``repeats - 2``), more for small sizes (:func:`~benchmarks.harness.repeats_for`, the same for
both). Prints one JSON object: for each size, points/s of
jaxgeo (numpy in and out, the shared guarded Newton, a convergence flag per point) and of GDAL's
RPC transformer (rasterio ``RPCTransformer.xy``, GDAL's own iterative inverse), their ratio, the
fraction of points jaxgeo flags as converged, the max re-projection error of each (px) and the
max disagreement in degrees; the same for shareloc (``direct_loc_h``) and rpcm
(``localization``) with GDAL's number of calls. A peer that is not installed is named at the top,
not estimated.
"""

from __future__ import annotations

import argparse
import pathlib
import platform

import jax
import numpy as np
import rasterio
from rasterio.transform import RPCTransformer

import jaxgeo
from benchmarks.data import PLEIADES_TIF as TIF
from benchmarks.harness import best_time, emit, ratio_vs, repeats_for
from benchmarks.peers import rpc as rpc_peers
from jaxgeo.io import from_rasterio_rpc


def gdal_localize(rpcs, xy: np.ndarray, h: np.ndarray) -> np.ndarray:
    with RPCTransformer(rpcs) as t:
        # GDAL pixel/line = ours + 0.5
        lon, lat = t.xy(xy[:, 1] + 0.5, xy[:, 0] + 0.5, zs=h, offset="ul")
    return np.stack([np.asarray(lon), np.asarray(lat), h], axis=-1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e4, 1e6])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--tif", type=pathlib.Path, default=TIF)
    args = parser.parse_args()

    with rasterio.open(args.tif) as src:
        rpcs = src.rpcs
    rpc = from_rasterio_rpc(rpcs, str(args.tif))
    peers = rpc_peers.load(args.tif, "localize")
    rng = np.random.default_rng(0)
    results = []
    for size in args.sizes:
        n = int(size)
        truth = np.asarray(rpc.ground_offset) + rng.uniform(-0.9, 0.9, (n, 3)) * np.asarray(
            rpc.ground_scale
        )
        xy = np.asarray(rpc.project(truth))
        h = truth[:, 2].copy()
        reps = repeats_for(n, args.repeats)
        t_jax, g_jax = best_time(lambda xy=xy, h=h: rpc.localize(xy, h), reps)
        reps = repeats_for(n, max(1, args.repeats - 2))
        t_gdal, g_gdal = best_time(lambda xy=xy, h=h: gdal_localize(rpcs, xy, h), reps)
        row = {}
        for name, (model, fn) in peers.items():
            if isinstance(model, str):  # not installed: reported at the top, not estimated
                continue
            t, g = best_time(lambda xy=xy, h=h, m=model, f=fn: f(m, xy, h), reps)
            row[f"{name}_points_per_s"] = n / t
            row |= ratio_vs(t_jax, {name: t})
            row[f"max_reprojection_px_{name}"] = float(
                np.nanmax(np.abs(np.asarray(rpc.project(g)) - xy))
            )
            row[f"max_diff_vs_{name}_deg"] = float(np.nanmax(np.abs(g_jax[:, :2] - g[:, :2])))
        ok = np.all(np.isfinite(g_jax), axis=-1)
        err_jax = np.abs(np.asarray(rpc.project(g_jax[ok])) - xy[ok]).max()
        err_gdal = np.nanmax(np.abs(np.asarray(rpc.project(g_gdal)) - xy))
        results.append(
            {
                "points": n,
                "jaxgeo_points_per_s": n / t_jax,
                "gdal_points_per_s": n / t_gdal,
                **ratio_vs(t_jax, {"gdal": t_gdal}),
                "converged_fraction": float(ok.mean()),
                "max_reprojection_px_jaxgeo": float(err_jax),
                "max_reprojection_px_gdal": float(err_gdal),
                "max_diff_vs_gdal_deg": float(np.nanmax(np.abs(g_jax[:, :2] - g_gdal[:, :2]))),
            }
            | row
        )
    emit(
        {
            "benchmark": "rpc_localization",
            "jax_backend": jax.default_backend(),
            "devices": [str(d) for d in jax.devices()],
            "cpu": platform.processor() or platform.machine(),
            "jaxgeo": jaxgeo.__version__,
            "gdal": rasterio.__gdal_version__,
            **rpc_peers.versions(peers),
            "results": results,
        }
    )


if __name__ == "__main__":
    main()
