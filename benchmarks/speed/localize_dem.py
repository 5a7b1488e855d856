"""``localize_on_dem`` against ``localize`` at a constant height, and against the robust search
alone (before issue 54), same run: an RPC and a physical model.

    JAXGEO_CACHE_DIR=$(mktemp -d) python -m benchmarks.speed.localize_dem [--sizes 1e4 1e5]

Models: the real Pleiades RPC of ``benchmarks.data`` and a simulated Cartosat-1 image
(:func:`jaxgeo.simulate.cartosat1_stereo`, an :class:`~jaxgeo.models.EphemerisModel`), each over
a :class:`~jaxgeo.models.DEMGrid` of hills (500-1100 m, 400 x 400 cells, ~80 m (RPC) and ~165 m
(Cartosat-1)). Points uniform over the image. Cases, timed interleaved round by round (the
best and the median of ``--rounds`` calls each, after a first call whose time, ``first_s``,
includes tracing and compiling unless the kept programs were on disk: run with an empty
``JAXGEO_CACHE_DIR`` for a cold first call):

- ``localize``: ``model.localize(xy, h)`` at the DEM's mean height (the RPC: numpy in and
  out, its kernel; the physical model: the same call jitted, numpy in);
- ``dem``: ``model.localize_on_dem(xy, grid)``, numpy in and out (the fast search, the robust
  one for the points it leaves);
- ``dem_before``: the robust search alone over all the points in one jitted program (what
  ``localize_on_dem`` ran before issue 54).

``ratio_vs_localize`` = a case's time over ``localize``'s, the median of the per-round ratios
(compilation excluded); ``first_s`` the first call (compilation included). Agreement of
``dem`` with ``dem_before``: statuses point by point, the largest difference on the OK points
(deg, m), and the share of points the fast search left to the robust one.
"""

from __future__ import annotations

import argparse
import os
import time

import equinox as eqx
import jax
import numpy as np

from benchmarks.harness import emit, wait
from benchmarks.speed.localize_traced import interleaved, pleiades_rpc


def hills_around(lon0: float, lat0: float, span_deg: float, n: int = 400):
    """A DEMGrid of hills (500-1100 m) over ``span_deg`` around ``(lon0, lat0)``."""
    from jaxgeo.models import DEMGrid

    step = span_deg / n
    lon = lon0 - span_deg / 2 + step * np.arange(n)
    lat = lat0 + span_deg / 2 - step * np.arange(n)
    lon_g, lat_g = np.meshgrid(lon, lat)
    z = 800 + 300 * np.sin(lon_g * 60) * np.cos(lat_g * 50)
    return DEMGrid(z, (lon[0], lat[0]), (step, -step))


def rpc_case():
    rpc = pleiades_rpc()
    lon0, lat0 = (float(v) for v in rpc.ground_offset[:2])
    lo, hi = (
        np.asarray(rpc.image_offset) - 0.5 * np.asarray(rpc.image_scale),
        np.asarray(rpc.image_offset) + 0.5 * np.asarray(rpc.image_scale),
    )
    return "pleiades_rpc", rpc, hills_around(lon0, lat0, 0.3), (lo, hi), None


def ephemeris_case():
    from jaxgeo.simulate import cartosat1_stereo

    scene = cartosat1_stereo(0)
    model = scene.truth[scene.names[0]]
    lon0, lat0 = (float(v) for v in np.asarray(model.reference_ground())[:2])
    size = np.array([float(model.n_cols), float(model.n_rows)])
    jitted = jax.jit(lambda m, a, h: m.localize(a, h))
    return (
        "cartosat1_ephemeris",
        model,
        hills_around(lon0, lat0, 0.66),
        (0 * size, size - 1),
        jitted,
    )


def make_calls(model, grid, xy, h, jitted, robust_all, options) -> dict:
    """The three cases of one model and size (see the module docstring)."""
    from jaxgeo.models import localize_on_dem

    if jitted is None:
        localize = lambda: model.localize(xy, h)  # noqa: E731
    else:
        localize = lambda: jitted(model, xy, h)  # noqa: E731
    return {
        "localize": localize,
        "dem": lambda: localize_on_dem(model, xy, grid),
        "dem_before": lambda: robust_all(model, grid, options, xy),
    }


def first_then_interleaved(calls: dict, rounds: int) -> tuple[dict, dict]:
    """First call of each (``first_s``: compilation or the kept program's load), then
    :func:`~benchmarks.speed.localize_traced.interleaved`'s rounds."""
    first = {}
    for name, fn in calls.items():
        t0 = time.perf_counter()
        wait(fn())
        first[name] = time.perf_counter() - t0
    return first, interleaved(calls, rounds)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e4, 1e5])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--models", nargs="+", default=["rpc", "ephemeris"])
    args = parser.parse_args(argv)
    from jaxgeo.models import _dem_fast, localize_on_dem

    robust_all = eqx.filter_jit(_dem_fast._robust_search)
    options = (4096, 100, 1e-6)
    rng = np.random.default_rng(0)
    results = []
    for which in args.models:
        name, model, grid, (lo, hi), jitted = {"rpc": rpc_case, "ephemeris": ephemeris_case}[
            which
        ]()
        h_mean = float(np.nanmean(np.asarray(grid.heights_m)))
        for size in args.sizes:
            n = int(size)
            xy = lo + rng.random((n, 2)) * (hi - lo)
            h = np.full(n, h_mean)
            calls = make_calls(model, grid, xy, h, jitted, robust_all, options)
            first, times = first_then_interleaved(calls, args.rounds)
            cases = {}
            for case, runs in times.items():
                ratios = [a / b for a, b in zip(runs, times["localize"], strict=True)]
                cases[case] = {
                    "first_s": first[case],
                    "best_s": min(runs),
                    "median_s": float(np.median(runs)),
                    "points_per_s": n / min(runs),
                    "ratio_vs_localize": float(np.median(ratios)),
                    "ratio_vs_localize_range": [min(ratios), max(ratios)],
                    "runs_s": runs,
                }
            speedup = [a / b for a, b in zip(times["dem_before"], times["dem"], strict=True)]
            g, st = localize_on_dem(model, xy, grid)
            g0, st0 = (np.asarray(v) for v in robust_all(model, grid, options, xy))
            ok = (st == 0) & (st0 == 0)
            _, _, robust = _dem_fast._fast_chunk(model, grid, options, xy)
            results.append(
                {
                    "model": name,
                    "points": n,
                    "grid_cells": list(grid.heights_m.shape),
                    "cases": cases,
                    "dem_speedup_vs_before": float(np.median(speedup)),
                    "same_status": bool(np.array_equal(st, st0)),
                    "ok_fraction": float(np.mean(st == 0)),
                    "left_to_robust_fraction": float(np.mean(robust)),
                    "max_diff_vs_before_deg": float(np.max(np.abs(g[ok, :2] - g0[ok, :2]))),
                    "max_diff_vs_before_m": float(np.max(np.abs(g[ok, 2] - g0[ok, 2]))),
                }
            )
    return emit(
        {
            "benchmark": "localize_dem",
            "rounds": args.rounds,
            "cache_dir": os.environ.get("JAXGEO_CACHE_DIR", "default"),
            "results": results,
        }
    )


if __name__ == "__main__":
    main()
