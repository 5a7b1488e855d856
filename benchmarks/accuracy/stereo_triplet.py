"""DSM of the s2p Pleiades triplet against s2p's expected DSM (issue 13's check).

    python -m benchmarks.accuracy.stereo_triplet [--triangulation intersect|los_midpoint]
        [--no-register] [--json OUT.json]

Same input as s2p's end-to-end test (``../shared/data/real/s2p_triplet``, AGPL data read in
place, never copied): reference img_02, pairs with img_01 and img_03, ROI x=150 y=150 w=700
h=700 of img_02, 0.5 m cells on s2p's own grid (EPSG:32631, its origin and shape), so cells
compare one to one. Prints, over the cells both DSMs fill: median and 90th percentile of
|dh|, the mean dh, and the share of s2p's cells jaxgeo fills; plus run times per stage and the
machine (:func:`benchmarks.harness.emit`).
"""

import argparse
import json
import pathlib
import time

import jax
import numpy as np
import rasterio

from benchmarks.data import S2P_TRIPLET as SHARED
from benchmarks.harness import emit
from jaxgeo.io import read_rpc
from jaxgeo.stereo import DSMSettings, dsm_from_images

jax.config.update("jax_enable_x64", True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(SHARED))
    ap.add_argument("--triangulation", default="intersect")
    ap.add_argument("--no-register", action="store_true")
    ap.add_argument("--json")
    args = ap.parse_args()
    folder = pathlib.Path(args.data)
    paths = [folder / f"img_0{i}.tif" for i in (2, 1, 3)]
    models = [read_rpc(p) for p in paths]
    with rasterio.open(folder / "expected_dsm.tif") as f:
        ref, tr = f.read(1), f.transform
    t0 = time.perf_counter()
    dsm, stats = dsm_from_images(
        models, paths,
        DSMSettings(roi=(150, 150, 700, 700), res_m=0.5, epsg=32631,
                    triangulation=args.triangulation, register=not args.no_register),
        origin=(tr.c, tr.f), shape=ref.shape, progress=True,
    )  # fmt: skip
    elapsed = time.perf_counter() - t0
    h = dsm.height
    both = np.isfinite(h) & np.isfinite(ref)
    dh = (h - ref)[both]
    out = {
        "triangulation": args.triangulation,
        "register": not args.no_register,
        "median_abs_dh_m": float(np.median(np.abs(dh))),
        "p90_abs_dh_m": float(np.percentile(np.abs(dh), 90)),
        "p99_abs_dh_m": float(np.percentile(np.abs(dh), 99)),
        "mean_dh_m": float(np.mean(dh)),
        "fill_of_s2p_cells": float(both.sum() / np.isfinite(ref).sum()),
        "cells_jaxgeo": int(np.isfinite(h).sum()),
        "cells_s2p": int(np.isfinite(ref).sum()),
        "seconds": round(elapsed, 1),
        "pairs": stats,
    }
    out = emit(out, default=str)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
