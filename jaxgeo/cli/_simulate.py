"""``jaxgeo simulate``: write a simulated scene (vendor RPCs, truth, images) to a folder.

    jaxgeo simulate cartosat1 --seed S --out DIR [--site hobart|warsaw] [--overwrite]
    jaxgeo simulate carto2s-strip --scenes N --seed S --out DIR [--gcp-every K] [--overwrite]
    jaxgeo simulate stereo-scene --size N --seed S [--jitter-px A] [--jitter-period-lines P]
                                 [--exact-rpc] [--relief-m M] --out DIR [--overwrite] [--quiet]

Existing files in DIR are never replaced unless ``--overwrite`` is given (checked before any
work; nothing is written then). ``cartosat1`` and ``carto2s-strip`` write files ready for
``jaxgeo adjust`` (RPC text files, ``ground.csv``, ``observations.csv``) with the truth in
``truth.json``.

stereo-scene renders a Pleiades-like pushbroom stereo pair of N x N px (GSD 0.67 m,
base/height 0.45) through its true physical models over a textured synthetic terrain,
streamed to disk block by block (memory independent of N), into DIR:
  left.tif, right.tif  the images (left looks forward, right backward), uint16 12-bit,
                       tiled 256 x 256, each with its vendor RPC in the GeoTIFF RPC tag
                       (as GDAL and jaxgeo.io.read_rpc read it), no geotransform
  truth_dsm.tif        the true surface: ellipsoidal heights (m), local UTM, cells of
                       about the GSD, float32, NaN outside the area both images see
  truth.json           what rebuilds the true models (jitter-free EphemerisModels and
                       the jitter), the vendor models and RPC fit errors, terrain,
                       texture, and a grid of true ground points with their true image
                       coordinates (jaxgeo.simulate.read_stereo_scene reads it back)
The RPCs are fitted without the jitter (as a vendor's would be), to a copy of the truth
with a few pixels of pointing error, or to the exact models with --exact-rpc (then they
reproject truth points to the true pixel to ~1e-5 px). Deterministic in the seed.
"""

from __future__ import annotations

import argparse

from ._common import add_command, add_json, add_out, add_quiet


def register(sub) -> None:
    line = "write a simulated Cartosat-1 pair, Carto-2S strip or rendered stereo scene"
    parser = add_command(sub, "simulate", line, __doc__)
    kinds = parser.add_subparsers(dest="kind", required=True, metavar="KIND")

    def common(p: argparse.ArgumentParser, noise: bool = True) -> None:
        p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
        add_out(p, "DIR", "output folder (created if missing)")
        if noise:
            p.add_argument("--noise-px", type=float, default=0.3, help="image noise std (px)")
        p.set_defaults(func=run)

    p = kinds.add_parser("cartosat1", help="Cartosat-1 fore/aft stereo pair (fore.txt, aft.txt)")
    common(p)
    p.add_argument(
        "--site",
        choices=("hobart", "warsaw"),
        default="hobart",
        help="hobart: 69 points in one quarter, 0..1260 m; warsaw: 36 spread, flat",
    )
    p.add_argument("--gcps", type=int, default=9, help="number of GCPs (rest: check points)")

    p = kinds.add_parser("carto2s-strip", help="Carto-2S strip of sub-scenes (scene_000.txt ...)")
    common(p)
    p.add_argument("--scenes", type=int, default=80, help="number of sub-scenes (default 80)")
    p.add_argument("--gcp-every", type=int, default=4, help="GCPs in every K-th scene (default 4)")

    p = kinds.add_parser(
        "stereo-scene",
        help="rendered Pleiades-like stereo pair with RPCs and truth (left.tif, right.tif, "
        "truth_dsm.tif, truth.json)",
        description=__doc__.split("\n\n")[3],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    common(p, noise=False)
    p.add_argument("--size", type=int, required=True, metavar="N", help="image size, N x N px")
    p.add_argument(
        "--jitter-px",
        type=float,
        default=0.0,
        metavar="A",
        help="amplitude (px) of a sinusoidal attitude jitter of the true models, across track "
        "(along track a quarter of it); the delivered RPCs are fitted without it (default 0)",
    )
    p.add_argument(
        "--jitter-period-lines",
        type=float,
        default=1000.0,
        metavar="P",
        help="period of the jitter in image lines (default 1000)",
    )
    p.add_argument(
        "--exact-rpc",
        action="store_true",
        help="deliver RPCs fitted to the exact (jitter-free) true models, not to a copy with "
        "a few pixels of pointing error",
    )
    p.add_argument(
        "--relief-m",
        type=float,
        metavar="M",
        help="terrain relief in metres (default: a tenth of the footprint, 30..300 m)",
    )
    add_quiet(p)
    add_json(p)


def run(args: argparse.Namespace) -> int:
    import pathlib

    from ..simulate import (
        carto2s_strip,
        cartosat1_stereo,
        check_writable,
        stereo_output_files,
        strip_output_files,
    )
    from . import CommandError

    out = pathlib.Path(args.out)
    if out.exists() and not out.is_dir():
        raise CommandError(f"--out {out}: exists and is not a directory")
    if args.kind == "stereo-scene":
        return _stereo_scene(args, out)
    if args.kind == "cartosat1":
        if args.gcps < 0:
            raise CommandError(f"--gcps must be >= 0, got {args.gcps}")
        check_writable(stereo_output_files(out), args.overwrite)  # before any work
        scene = cartosat1_stereo(
            args.seed, site=args.site, n_gcps=args.gcps, image_noise_px=args.noise_px
        )
    else:
        if args.scenes < 1:
            raise CommandError(f"--scenes must be >= 1, got {args.scenes}")
        if args.gcp_every < 1:
            raise CommandError(f"--gcp-every must be >= 1, got {args.gcp_every}")
        check_writable(strip_output_files(out, args.scenes), args.overwrite)
        scene = carto2s_strip(
            args.scenes, args.seed, gcp_every=args.gcp_every, image_noise_px=args.noise_px
        )
    paths = scene.save(out, overwrite=args.overwrite)
    acc = scene.accuracy()
    print(f"wrote {len(paths)} files to {out}")
    if args.kind == "cartosat1":
        img = ", ".join(f"{n} {v['rms']:.1f} px" for n, v in acc["image_px"].items())
        inter = acc["intersection_m"]
        print(f"vendor RPC direct georeferencing: {img}; forward intersection "
              f"{inter['rms_plan']:.1f} m planimetry, {inter['rms_h']:.1f} m height")  # fmt: skip
    else:
        print(f"vendor RPC direct georeferencing: {acc['rms_min']:.1f} .. {acc['rms_max']:.1f} px "
              f"RMS per sub-scene")  # fmt: skip
    return 0


def _stereo_scene(args: argparse.Namespace, out) -> int:
    import time

    from ..simulate import (
        check_writable,
        stereo_scene_files,
        stereo_scene_truth,
        write_stereo_scene,
    )
    from ._common import note, print_json

    check_writable(stereo_scene_files(out), args.overwrite)  # before any work
    start = time.perf_counter()
    note(f"simulating a {args.size} x {args.size} px stereo scene (seed {args.seed})", args.quiet)
    scene = stereo_scene_truth(
        args.size, args.seed, jitter_px=args.jitter_px,
        jitter_period_lines=args.jitter_period_lines, exact_rpc=args.exact_rpc,
        relief_m=args.relief_m,
    )  # fmt: skip
    models_s = time.perf_counter() - start
    paths = write_stereo_scene(scene, out, overwrite=args.overwrite, progress=not args.quiet)
    total_s = time.perf_counter() - start
    info = scene.info
    fit = {n: info["rpc_fit"][n]["check_max_px"] for n in info["rpc_fit"]}
    vs = {n: info["rpc_vs_truth"][n] for n in info["rpc_vs_truth"]}
    summary = {
        "out": str(out),
        "files": [p.name for p in paths],
        "size": args.size,
        "gsd_m": info["gsd_m"],
        "base_to_height": info["base_to_height"],
        "relief_m": info["params"]["relief_m"],
        "jitter_px": args.jitter_px,
        "rpc_fit_check_max_px": fit,
        "rpc_vs_truth_rms_px": {n: v["nojitter_px"]["rms"] for n, v in vs.items()},
        "rpc_vs_jittered_truth_rms_px": {n: v["jittered_px"]["rms"] for n, v in vs.items()},
        "dsm_shape": [scene.dsm.rows, scene.dsm.cols],
        "dsm_res_m": scene.dsm.res_m,
        "models_s": round(models_s, 2),
        "total_s": round(total_s, 2),
    }
    if args.json:
        print_json(summary)
        return 0
    print(f"wrote {', '.join(summary['files'])} to {out} in {total_s:.1f} s")
    print(f"GSD {info['gsd_m']:.3f} m, base/height {info['base_to_height']:.2f}, relief "
          f"{info['params']['relief_m']:.0f} m, truth DSM {scene.dsm.rows} x {scene.dsm.cols} "
          f"cells of {scene.dsm.res_m} m (EPSG:{scene.dsm.epsg})")  # fmt: skip
    what = "the exact models" if args.exact_rpc else "the vendor's models (pointing error)"
    print(f"RPCs fitted without the jitter to {what}:")
    for n in fit:
        print(f"  {n}: fit error {fit[n]:.1e} px max (check grid); RPC minus the jitter-free "
              f"true model {vs[n]['nojitter_px']['rms']:.2g} px RMS, minus the jittered one "
              f"{vs[n]['jittered_px']['rms']:.2g} px RMS (truth points)")  # fmt: skip
    return 0
