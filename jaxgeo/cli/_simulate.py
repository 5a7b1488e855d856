"""``jaxgeo simulate``: write a simulated scene (vendor RPCs, GCP/check tables, truth) to a folder.

    jaxgeo simulate cartosat1 --seed S --out DIR [--site hobart|warsaw] [--overwrite]
    jaxgeo simulate carto2s-strip --scenes N --seed S --out DIR [--gcp-every K] [--overwrite]

Existing files in DIR are never replaced unless ``--overwrite`` is given (nothing is written
then). The files are ready for ``jaxgeo adjust`` (RPC text files, ``ground.csv``,
``observations.csv``) and carry the truth in ``truth.json``.
"""

from __future__ import annotations

import argparse


def register(sub) -> None:
    parser = sub.add_parser(
        "simulate",
        help="write a simulated Cartosat-1 stereo pair or Carto-2S strip",
        description=__doc__.split("\n\n")[0],
    )
    kinds = parser.add_subparsers(dest="kind", required=True, metavar="KIND")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
        p.add_argument("--out", required=True, metavar="DIR", help="output folder")
        p.add_argument("--overwrite", action="store_true", help="replace existing files")
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
