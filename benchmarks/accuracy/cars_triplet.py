"""CARS (CNES) on the s2p Pleiades triplet against s2p's expected DSM (issue 13's peer check).

    python -m benchmarks.accuracy.cars_triplet --run --cars-env /tmp/carsenv [--workers 2]
        [--out /tmp/cars_triplet] [--jaxgeo-dsm J.tif] [--json OUT.json]
    python -m benchmarks.accuracy.cars_triplet --cars-dsm OUT/dsm/dsm.tif --seconds S [...]

CARS is a peer, not a dependency: ``python3 -m venv /tmp/carsenv && /tmp/carsenv/bin/pip
install cars``. ``--run`` writes the CARS configuration (same input as ``stereo_triplet``:
img_02 paired with img_01 and img_03, RPCs from the TIFF tags; output ROI = the extent of
s2p's expected DSM; EPSG:32631; heights above the WGS84 ellipsoid, ``output.geoid: false``,
as s2p's; local multiprocessing orchestrator) and times ``cars`` end to end. CARS's default
resolution is 0.5 m here (an explicit ``output.resolution`` with an ROI crashes CARS 1.3.0)
and ``phasing`` puts its cell edges on s2p's grid, so the nearest-neighbour reprojection onto
s2p's grid copies cells one to one. Prints the statistics of ``stereo_triplet`` over the cells
both fill (dh = CARS - s2p), also without the cells CARS marks as interpolated, and of CARS
against a jaxgeo DSM on s2p's grid if one is given (``stereo_triplet``'s run, written with
``jaxgeo.stereo.write_dsm``). Without ``--run``, ``--seconds`` is the time of the CARS run
that wrote ``--cars-dsm``. The machine comes last (:func:`benchmarks.harness.emit`).
"""

import argparse
import json
import pathlib
import re
import subprocess
import time

import numpy as np
import rasterio
from rasterio.warp import Resampling, reproject

from benchmarks.data import S2P_TRIPLET as SHARED
from benchmarks.harness import emit


def cars_conf(data, out, workers, ref):
    x0, y0, x1, y1 = ref.bounds
    ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
    roi = {
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "EPSG:32631"}},
        "features": [
            {
                "type": "Feature",
                "properties": {},
                "geometry": {"type": "Polygon", "coordinates": [ring]},
            }
        ],
    }
    phasing = {"point": [x0, y1], "epsg": 32631, "unit": "meter"}
    return {
        "input": {
            "sensors": {
                f"img{i}": {"image": str(data / f"img_{i}.tif")} for i in ("02", "01", "03")
            },
            "pairing": [["img02", "img01"], ["img02", "img03"]],
            "roi": roi,
        },
        "output": {"directory": str(out), "epsg": 32631, "geoid": False},
        "orchestrator": {"mode": "multiprocessing", "nb_workers": workers},
        "surface_modeling": {"advanced": {"all": {"phasing": phasing}}},
    }


def on_grid(path, ref):
    """Band 1 of ``path`` on ``ref``'s grid (nearest), NaN where no data."""
    out = np.full(ref.shape, np.nan, np.float32)
    with rasterio.open(path) as f:
        reproject(
            rasterio.band(f, 1), out, src_nodata=f.nodata, dst_transform=ref.transform,
            dst_crs=ref.crs, dst_nodata=np.nan, resampling=Resampling.nearest,
        )  # fmt: skip
    return out


def stats(h, ref, name, ref_name):
    """dh = h - ref over the cells both fill."""
    both = np.isfinite(h) & np.isfinite(ref)
    dh = (h - ref)[both]
    a = np.abs(dh)
    return {
        "median_abs_dh_m": float(np.median(a)),
        "p90_abs_dh_m": float(np.percentile(a, 90)),
        "p99_abs_dh_m": float(np.percentile(a, 99)),
        "mean_dh_m": float(np.mean(dh)),
        f"fill_of_{ref_name}_cells": float(both.sum() / np.isfinite(ref).sum()),
        f"cells_{name}": int(np.isfinite(h).sum()),
        f"cells_{ref_name}": int(np.isfinite(ref).sum()),
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(SHARED))
    ap.add_argument("--run", action="store_true")
    ap.add_argument("--cars-env", default="/tmp/carsenv")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="/tmp/cars_triplet")
    ap.add_argument("--cars-dsm")
    ap.add_argument("--seconds", type=float)
    ap.add_argument("--jaxgeo-dsm")
    ap.add_argument("--json")
    args = ap.parse_args()
    data, out = pathlib.Path(args.data), pathlib.Path(args.out)
    ref = rasterio.open(data / "expected_dsm.tif")
    seconds, dsm = args.seconds, args.cars_dsm
    if args.run:
        out.mkdir(parents=True, exist_ok=True)
        conf = cars_conf(data, out / "out", args.workers, ref)
        (out / "conf.json").write_text(json.dumps(conf, indent=1))
        cars = pathlib.Path(args.cars_env) / "bin" / "cars"
        t0 = time.perf_counter()
        with open(out / "cars.log", "w") as log:
            subprocess.run(
                [str(cars), "--logtype", "plain", str(out / "conf.json")],
                stdout=log,
                stderr=log,
                check=True,
            )
        seconds, dsm = time.perf_counter() - t0, out / "out" / "dsm" / "dsm.tif"
    dsm = pathlib.Path(dsm)
    with rasterio.open(dsm) as f:
        ellipsoidal = "ellipsoidal height" in f.crs.to_wkt()
        offset = [
            (f.transform.c - ref.transform.c) / 0.5 % 1,
            (f.transform.f - ref.transform.f) / 0.5 % 1,
        ]
    if not ellipsoidal:
        raise SystemExit(
            f"{dsm}: heights not above the ellipsoid; run CARS with output.geoid false"
        )
    meta = (dsm.parents[1] / "metadata.yaml").read_text()
    used = (dsm.parents[1] / "global_used_conf.yaml").read_text()
    s2p = ref.read(1)
    h = on_grid(dsm, ref)
    interpolated = on_grid(dsm.parent / "filling.tif", ref) == 3  # 3: CARS's "interpolation"
    result = {
        "cars_version": re.search(r"version: (\S+)", meta).group(1),
        **stats(h, s2p, "cars", "s2p"),
        "seconds": None if seconds is None else round(seconds, 1),
        "nb_workers": int(re.search(r"nb_workers: (\d+)", used).group(1)),
        "cars_dsm": str(dsm),
        "heights": "WGS84 ellipsoid (CARS output.geoid false; s2p's DSM is ellipsoidal too)",
        "resampling": "nearest onto s2p's grid",
        "grid_offset_cells": offset,
        "cars_interpolated_cells": int(interpolated.sum()),
        "without_interpolated": stats(np.where(interpolated, np.nan, h), s2p, "cars", "s2p"),
    }
    if args.jaxgeo_dsm:
        jax_h = on_grid(args.jaxgeo_dsm, ref)
        result["jaxgeo_dsm"] = args.jaxgeo_dsm
        result["cars_vs_jaxgeo"] = stats(h, jax_h, "cars", "jaxgeo")
        result["jaxgeo_vs_s2p"] = stats(jax_h, s2p, "jaxgeo", "s2p")
    result = emit(result)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
