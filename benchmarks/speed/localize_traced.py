"""RPC localisation inside a user's own ``jax.jit`` / ``vmap`` against the numpy call, same run.

    python -m benchmarks.speed.localize_traced [--points 1e6] [--dem-points 1e4] [--rounds 7]

``rpc.localize(xy, h)`` given numpy arrays runs jaxgeo's compiled kernel (chunks of points,
numpy out); a user who writes ``jax.jit(lambda m, xy, h: m.localize(xy, h))`` (or vmaps it per
point) gets the traced path, which must keep up with it. Timed, interleaved round by round
(the best and the median of ``--rounds`` calls each, after a warm-up; the machine is shared):
``numpy`` (the kernel), ``jit`` (the whole arrays in one jitted call), ``vmap`` (jitted, vmapped
over points), and with ``--generic`` ``generic`` (the base class's per-point Newton:
``AbstractSensorModel.localize``, what the traced path was before). Localisation on a DEM
(``model.localize_on_dem`` on a :class:`~jaxgeo.models.DEMGrid` of hills over the scene):
``dem_numpy`` (numpy in, the call as a user writes it) and ``dem_jit`` (inside ``jax.jit``).
Per case: points/s, and ``speed_vs_numpy`` = the numpy call's time over the case's (the median
of the per-round ratios; >= 0.8 is the target of issue 29), the NaN flags compared point by
point and the largest difference in degrees. The real Pleiades RPC of ``benchmarks.data``
(uniform points over 90 % of its validity cube).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import emit, wait


def pleiades_rpc():
    import rasterio

    from benchmarks.data import PLEIADES_TIF
    from jaxgeo.io import from_rasterio_rpc

    with rasterio.open(PLEIADES_TIF) as src:
        return from_rasterio_rpc(src.rpcs, str(PLEIADES_TIF))


def hills(rpc, n: int = 400, span_deg: float = 0.3):
    """A DEMGrid of smooth hills (500-1100 m) over ``span_deg`` around the scene's centre."""
    from jaxgeo.models import DEMGrid

    lon0, lat0 = (float(v) for v in rpc.ground_offset[:2])
    step = span_deg / n
    lon = lon0 - span_deg / 2 + step * np.arange(n)
    lat = lat0 + span_deg / 2 - step * np.arange(n)
    lon_g, lat_g = np.meshgrid(lon, lat)
    z = 800 + 300 * np.sin(lon_g * 60) * np.cos(lat_g * 50)
    return DEMGrid(z, (lon[0], lat[0]), (step, -step))


def interleaved(calls: dict, rounds: int) -> dict[str, list[float]]:
    """Each call once as warm-up, then ``rounds`` rounds of one timed call of each, the order
    reversed every other round (no case always runs after the same one)."""
    for fn in calls.values():
        wait(fn())
    times: dict[str, list[float]] = {k: [] for k in calls}
    names = list(calls)
    for r in range(rounds):
        for name in names if r % 2 == 0 else names[::-1]:
            t0 = time.perf_counter()
            wait(calls[name]())
            times[name].append(time.perf_counter() - t0)
    return times


def compare(reference: np.ndarray, other) -> dict:
    """NaN flags point by point and the largest difference (deg / m) of the others."""
    other = np.asarray(other)
    same = np.array_equal(np.isnan(reference), np.isnan(other))
    ok = np.isfinite(reference) & np.isfinite(other)
    diff = float(np.max(np.abs(reference[ok] - other[ok]))) if ok.any() else 0.0
    return {"same_nan_flags": bool(same), "max_diff": diff}


def summary(times: dict[str, list[float]], points: int, reference: str) -> dict:
    out = {}
    for name, runs in times.items():
        ratios = [a / b for a, b in zip(times[reference], runs, strict=True)]
        out[name] = {
            "best_s": min(runs),
            "median_s": float(np.median(runs)),
            "points_per_s": points / min(runs),
            "speed_vs_numpy": float(np.median(ratios)),
            "speed_vs_numpy_range": [min(ratios), max(ratios)],
            "runs_s": runs,
        }
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=float, default=1e6)
    parser.add_argument("--dem-points", type=float, default=1e4)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--generic", action="store_true", help="also the per-point Newton")
    args = parser.parse_args(argv)
    from jaxgeo.models import AbstractSensorModel

    rpc = pleiades_rpc()
    rng = np.random.default_rng(0)
    n = int(args.points)
    truth = np.asarray(rpc.ground_offset) + rng.uniform(-0.9, 0.9, (n, 3)) * np.asarray(
        rpc.ground_scale
    )
    xy = np.asarray(rpc.project(truth))
    h = truth[:, 2].copy()
    xy_j, h_j = jnp.asarray(xy), jnp.asarray(h)
    jit = jax.jit(lambda m, a, b: m.localize(a, b))
    vmap = jax.jit(lambda m, a, b: jax.vmap(lambda p, z: m.localize(p, z))(a, b))
    calls = {
        "numpy": lambda: rpc.localize(xy, h),
        "jit": lambda: jit(rpc, xy_j, h_j),
        "vmap": lambda: vmap(rpc, xy_j, h_j),
    }
    if args.generic:
        generic = jax.jit(lambda m, a, b: AbstractSensorModel.localize(m, a, b))
        calls["generic"] = lambda: generic(rpc, xy_j, h_j)
    times = interleaved(calls, args.rounds)
    reference = np.asarray(calls["numpy"]())
    result = {"points": n, "rounds": args.rounds, "localize": summary(times, n, "numpy")}
    for name in calls:
        if name != "numpy":
            result["localize"][name] |= compare(reference, calls[name]())
    result["max_reprojection_px"] = float(
        np.nanmax(np.abs(np.asarray(rpc.project(reference)) - xy))
    )

    grid = hills(rpc)
    m = int(args.dem_points)
    go, gs = np.asarray(rpc.image_offset), np.asarray(rpc.image_scale)
    dem_xy = go + rng.uniform(-0.5, 0.5, (m, 2)) * gs
    dem_jit = jax.jit(lambda model, a, g: model.localize_on_dem(a, g))
    dem_xy_j = jnp.asarray(dem_xy)
    dem_calls = {
        "dem_numpy": lambda: rpc.localize_on_dem(dem_xy, grid),
        "dem_jit": lambda: dem_jit(rpc, dem_xy_j, grid),
    }
    t0 = time.perf_counter()
    times = interleaved(dem_calls, max(3, args.rounds // 2))
    dem = summary(times, m, "dem_numpy")
    dem_ref, status = (np.asarray(v) for v in dem_calls["dem_numpy"]())
    dem["dem_jit"] |= compare(dem_ref, dem_calls["dem_jit"]()[0])
    result["dem"] = dem | {
        "points": m,
        "grid_cells": list(grid.heights_m.shape),
        "ok_fraction": float(np.mean(status == 0)),
        "wall_s": time.perf_counter() - t0,
    }
    return emit(result)


if __name__ == "__main__":
    main()
