"""RPC projection speed: ``rpc.project(numpy array)`` as README writes it, against numpy, GDAL's
RPC transformer, shareloc, rpcm (when installed: ``benchmarks/peers/rpc.py``) and the previous
monomial-form kernel, same run.

    python -m benchmarks.speed.projection [--sizes 1e2 1e4 1e6 1e7] [--repeats 20]

Prints one JSON object: for each size, points/s of each implementation (best of ``repeats``
calls after a warm-up, GDAL ``repeats - 2``; more calls for small sizes, the same number for
every implementation: :func:`benchmarks.harness.repeats_for`), the ratios, the fraction of the
compute bound (``--bound`` points/s; 184 flop and 40 B a point: ~850 M/s on the 2-core AVX-512
CPU of the issue) and the max disagreement in px. ``jaxgeo`` is the plain call
``rpc.project(ground)`` with numpy in and out (no jit written by the user), repeated on one
array: from its second use a size runs whole without copies (``jaxgeo.models._host``; the first
calls after compilation still pay page faults for ~8 calls while the allocator settles, hence 20
repeats); ``jaxgeo_one_off`` calls sizes used once each (``n - 1``, ``n - 2``...: the chunked
path); ``monomial_jit`` the former formulation (20 monomials, ``eqx.filter_jit``, jax array in).
The RPC is the real Pleiades scene of ../shared/data/real (read by GDAL itself). Timing, ratios
and the machine entry: :mod:`benchmarks.harness`.
"""

from __future__ import annotations

import argparse
import itertools
import pathlib
import platform

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import rasterio
from rasterio.transform import RPCTransformer

import jaxgeo
from benchmarks.data import PLEIADES_TIF as TIF
from benchmarks.harness import best_time, emit, ratio_vs, repeats_for
from benchmarks.peers import rpc as rpc_peers
from jaxgeo.io import from_rasterio_rpc
from jaxgeo.models.internal import monomials


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


def _monomial_project(rpc, ground):
    """The former kernel: 20 stacked monomials, term-by-term sums (``eqx.filter_jit``)."""
    terms = [m for m in jnp.moveaxis(monomials(rpc.normalize_ground(ground)), -1, 0)]
    poly = lambda c: sum(c[k] * terms[k] for k in range(20))  # noqa: E731
    x = poly(rpc.num[0]) / poly(rpc.den[0])
    y = poly(rpc.num[1]) / poly(rpc.den[1])
    return rpc.image_offset + rpc.image_scale * jnp.stack([x, y], axis=-1)


def gdal_project(rpcs, ground: np.ndarray) -> np.ndarray:
    with RPCTransformer(rpcs) as t:
        rows, cols = t.rowcol(ground[:, 0], ground[:, 1], zs=ground[:, 2], op=lambda a: a)
    return np.stack([np.asarray(cols), np.asarray(rows)], axis=-1) - 0.5


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e2, 1e4, 1e6, 1e7])
    parser.add_argument("--bound", type=float, default=850e6)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--tif", type=pathlib.Path, default=TIF)
    args = parser.parse_args()

    with rasterio.open(args.tif) as src:
        rpcs = src.rpcs
    rpc = from_rasterio_rpc(rpcs, str(args.tif))
    vendor = {k: np.asarray(v) for k, v in rpc.to_vendor().items()}
    old = eqx.filter_jit(_monomial_project)
    peers = rpc_peers.load(args.tif, "project")

    results = []
    rng = np.random.default_rng(0)
    for size in args.sizes:
        n = int(size)
        ground = np.asarray(rpc.ground_offset) + rng.uniform(-1, 1, (n, 3)) * np.asarray(
            rpc.ground_scale
        )
        ground_dev = jax.device_put(ground)
        reps = repeats_for(n, args.repeats)
        t_jax, p_jax = best_time(lambda g=ground: rpc.project(g), reps)
        # sizes used once each (n - 1, n - 2, ...): the chunked path, no size-specific program
        # (below host.EXACT_MIN points every call takes that path; the sizes may then recur)
        sizes = itertools.cycle(range(n - 1, 0, -1))
        t_once, _ = best_time(lambda g=ground, s=sizes: rpc.project(g[: next(s)]), reps)
        t_old, _ = best_time(lambda g=ground_dev: old(rpc, g), reps)  # waited on by the harness
        t_np, p_np = best_time(lambda g=ground: numpy_project(vendor, g), reps)
        reps = repeats_for(n, max(1, args.repeats - 2))
        t_gdal, p_gdal = best_time(lambda g=ground: gdal_project(rpcs, g), reps)
        row = {}
        for name, (model, fn) in peers.items():
            if isinstance(model, str):  # not installed: reported at the top, not estimated
                continue
            t, p = best_time(lambda g=ground, m=model, f=fn: f(m, g), reps)
            row[f"{name}_points_per_s"] = n / t
            row |= ratio_vs(t_jax, {name: t})
            row[f"max_diff_vs_{name}_px"] = float(np.abs(p_jax - p).max())
        results.append(
            {
                "points": n,
                "jaxgeo_points_per_s": n / t_jax,
                "jaxgeo_one_off_points_per_s": n / t_once,
                "monomial_jit_points_per_s": n / t_old,
                "numpy_points_per_s": n / t_np,
                "gdal_points_per_s": n / t_gdal,
                "fraction_of_bound": n / t_jax / args.bound,
                **ratio_vs(t_jax, {"monomial_jit": t_old, "numpy": t_np, "gdal": t_gdal}),
                "max_diff_vs_gdal_px": float(np.abs(p_jax - p_gdal).max()),
                "max_diff_vs_numpy_px": float(np.abs(p_jax - p_np).max()),
            }
            | row
        )
    emit(
        {
            "benchmark": "rpc_projection",
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
