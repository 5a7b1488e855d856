"""Whole-scene DSM against CARS (CNES) on the same simulated pair: ``jaxgeo dsm`` and ``cars``,
each a fresh process tree timed with its peak memory, both against the simulation's truth.

    python -m benchmarks.speed.cars_scene --folder /tmp/dsm_2000 --cars-env /tmp/carsenv
        [--workers 2]

The scene is :mod:`benchmarks.speed.dsm_scene`'s (``FOLDER/scene``: ``jaxgeo simulate
stereo-scene --exact-rpc``; run that benchmark first, or the simulation command, to make it).
CARS is a peer, not a dependency: ``python3 -m venv /tmp/carsenv && /tmp/carsenv/bin/pip
install cars``. Both get the two images with their RPCs in the TIFF tags, as a vendor delivers
them, and the same number of worker processes (``--workers``; CARS's local multiprocessing
orchestrator), heights above the WGS84 ellipsoid (CARS ``output.geoid: false``), the truth's
UTM zone; CARS's default pipeline and resolution (0.5 m), jaxgeo at the GSD (its default with
``--res`` as ``dsm_scene`` runs it), no ROI: the whole scene. jaxgeo runs after one warm-up of a
1000 px ROI (its compilation cache), as in ``dsm_scene``; CARS needs none. Accuracy as
``dsm_scene``'s: each DSM against ``truth_dsm.tif`` on its own cells (median and NMAD of the
error, fill of the truth's cells). The ratio is CARS's wall time over jaxgeo's (> 1: jaxgeo is
faster), same run.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys

from benchmarks.data import REPO
from benchmarks.harness import emit
from benchmarks.speed.dsm_scene import accuracy
from benchmarks.speed.ortho_scene import measure


def cars_conf(scene: pathlib.Path, out: pathlib.Path, workers: int, epsg: int) -> dict:
    """CARS's configuration: the pair, ellipsoidal heights in ``epsg``, ``workers`` processes."""
    return {
        "input": {
            "sensors": {side: {"image": str(scene / f"{side}.tif")} for side in ("left", "right")},
            "pairing": [["left", "right"]],
        },
        "output": {"directory": str(out), "epsg": epsg, "geoid": False},
        "orchestrator": {"mode": "multiprocessing", "nb_workers": workers},
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--folder", required=True, help="dsm_scene's folder (FOLDER/scene)")
    p.add_argument("--cars-env", default="/tmp/carsenv", help="CARS's virtual environment")
    p.add_argument("--workers", type=int, default=2, help="worker processes of each")
    a = p.parse_args(argv)
    folder = pathlib.Path(a.folder)
    scene = folder / "scene"
    truth = json.loads((scene / "truth.json").read_text())
    label = f"{scene} ({truth['params']['size']} px, GSD {truth['gsd_m']:.3f} m)"
    import rasterio

    with rasterio.open(scene / "truth_dsm.tif") as f:
        epsg = f.crs.to_epsg()
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    cli = [sys.executable, "-m", "jaxgeo.cli"]
    res = round(float(truth["gsd_m"]), 2)
    left, right = str(scene / "left.tif"), str(scene / "right.tif")
    dsm = [*cli, "dsm", left, right, "--res", str(res), "--quiet", "--json", "--overwrite"]
    measure([*dsm, "--roi", "0", "0", "1000", "1000", "-o", str(folder / "warmup.tif")], env)
    ours = folder / "cars_scene_jaxgeo.tif"
    jx = measure([*dsm, "--workers", str(a.workers), "-o", str(ours)], env)
    jx.pop("stdout")
    jx["accuracy"] = accuracy(ours, scene / "truth_dsm.tif")

    out = folder / "cars"
    out.mkdir(parents=True, exist_ok=True)
    conf = out / "conf.json"
    conf.write_text(json.dumps(cars_conf(scene, out / "out", a.workers, epsg), indent=1))
    cars_env = dict(os.environ)
    cars_env.pop("PYTHONPATH", None)
    cars = measure([str(pathlib.Path(a.cars_env) / "bin" / "cars"), str(conf)], cars_env)
    cars.pop("stdout")
    cars_dsm = out / "out" / "dsm" / "dsm.tif"
    cars["accuracy"] = accuracy(cars_dsm, scene / "truth_dsm.tif")
    meta = next((out / "out").rglob("*.json"), None)
    emit({
        "scene": label,
        "workers": a.workers,
        "jaxgeo": {"res_m": res, **jx},
        "cars": {"dsm": str(cars_dsm), "metadata": str(meta), **cars},
        "cars_over_jaxgeo_wall": cars["wall_s"] / jx["wall_s"],
        "note": "fresh process trees, same run; peak memory summed over each tree",
    })  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
