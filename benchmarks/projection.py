"""RPC projection speed: jitted jaxgeo against numpy and GDAL's RPC transformer, same run.

    python benchmarks/projection.py [--sizes 1e6 1e7] [--repeats 3]

Prints one JSON object: for each size, points/s of each implementation (best of ``repeats``
after a warm-up) and the ratios jaxgeo/numpy and jaxgeo/GDAL, plus the max disagreement in px.
The RPC is the real Pleiades scene of ../shared/data/real (read by GDAL itself).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import time

import equinox as eqx
import jax
import numpy as np
import rasterio
from rasterio.transform import RPCTransformer

import jaxgeo
from jaxgeo.io import from_rasterio_rpc
from jaxgeo.models.rpc import RPC

HERE = pathlib.Path(__file__).resolve().parent
TIF = HERE.parent.parent / "shared/data/real/PHR1B_P_201709281038393_SEN_PRG_FC_178609-001.tif"


def numpy_project(v: dict, ground: np.ndarray) -> np.ndarray:
    """A plain vectorised numpy RFM (RPC00B), the way rpcm and most scripts write it."""
    lon = (ground[:, 0] - v["lon_off"]) / v["lon_scale"]
    lat = (ground[:, 1] - v["lat_off"]) / v["lat_scale"]
    h = (ground[:, 2] - v["height_off"]) / v["height_scale"]
    m = np.stack(
        [
            np.ones_like(lon), lon, lat, h, lon * lat, lon * h, lat * h, lon**2, lat**2, h**2,
            lat * lon * h, lon**3, lon * lat**2, lon * h**2, lon**2 * lat, lat**3, lat * h**2,
            lon**2 * h, lat**2 * h, h**3,
        ]
    )  # fmt: skip
    x = (v["samp_num"] @ m) / (v["samp_den"] @ m) * v["samp_scale"] + v["samp_off"]
    y = (v["line_num"] @ m) / (v["line_den"] @ m) * v["line_scale"] + v["line_off"]
    return np.stack([x, y], axis=-1)


def gdal_project(rpcs, ground: np.ndarray) -> np.ndarray:
    with RPCTransformer(rpcs) as t:
        rows, cols = t.rowcol(ground[:, 0], ground[:, 1], zs=ground[:, 2], op=lambda a: a)
    return np.stack([np.asarray(cols), np.asarray(rows)], axis=-1) - 0.5


def best_time(fn, repeats: int) -> tuple[float, object]:
    out = fn()  # warm-up (and compilation for jax)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e6, 1e7])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--tif", type=pathlib.Path, default=TIF)
    args = parser.parse_args()

    with rasterio.open(args.tif) as src:
        rpcs = src.rpcs
    rpc = from_rasterio_rpc(rpcs, str(args.tif))
    vendor = {k: np.asarray(v) for k, v in rpc.to_vendor().items()}
    project = eqx.filter_jit(RPC.project)

    results = []
    rng = np.random.default_rng(0)
    for size in args.sizes:
        n = int(size)
        ground = np.asarray(rpc.ground_offset) + rng.uniform(-1, 1, (n, 3)) * np.asarray(
            rpc.ground_scale
        )
        ground_dev = jax.device_put(ground)
        t_jax, p_jax = best_time(
            lambda g=ground_dev: project(rpc, g).block_until_ready(), args.repeats
        )
        t_np, p_np = best_time(lambda g=ground: numpy_project(vendor, g), args.repeats)
        t_gdal, p_gdal = best_time(lambda g=ground: gdal_project(rpcs, g), max(1, args.repeats - 2))
        p_jax = np.asarray(p_jax)
        results.append(
            {
                "points": n,
                "jaxgeo_points_per_s": n / t_jax,
                "numpy_points_per_s": n / t_np,
                "gdal_points_per_s": n / t_gdal,
                "ratio_vs_numpy": t_np / t_jax,
                "ratio_vs_gdal": t_gdal / t_jax,
                "max_diff_vs_gdal_px": float(np.abs(p_jax - p_gdal).max()),
                "max_diff_vs_numpy_px": float(np.abs(p_jax - p_np).max()),
            }
        )
    print(
        json.dumps(
            {
                "benchmark": "rpc_projection",
                "jax_backend": jax.default_backend(),
                "devices": [str(d) for d in jax.devices()],
                "cpu": platform.processor() or platform.machine(),
                "jaxgeo": jaxgeo.__version__,
                "gdal": rasterio.__gdal_version__,
                "results": results,
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
