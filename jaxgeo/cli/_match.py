"""``jaxgeo match``: tie points between images by SIFT matching guided by their sensor models.

    jaxgeo match IMG1 IMG2 [IMG3 ...] [--model IMG=RPCFILE ...] [--roi X Y W H]
                 [--heights HMIN HMAX] [--tol PX] [--sigma PX] -o observations.csv [--overwrite]

Every pair of images is matched (keypoints of the earlier image searched within ``--tol`` px of
the epipolar curve its model predicts in the later one, between heights HMIN and HMAX; default
the RPC's validity range); outliers across the epipolar direction are rejected. Output: the
observations CSV ``jaxgeo adjust`` reads (``id,image,x,y,sigma_px``, image = file stem, pixel
centres at integers). ``--roi`` restricts the keypoints of the first image (pixels).
"""

from __future__ import annotations

import argparse
import pathlib


def register(sub) -> None:
    parser = sub.add_parser(
        "match",
        help="tie points by SIFT matching guided by the sensor models",
        description=__doc__.split("\n\n")[0],
    )
    parser.add_argument("images", nargs="+", metavar="IMG", help="images (two or more)")
    parser.add_argument(
        "--model",
        action="append",
        default=[],
        metavar="IMG=RPCFILE",
        help="the RPC file of an image (default: the RPC in the image itself)",
    )
    parser.add_argument("--roi", type=int, nargs=4, metavar=("X", "Y", "W", "H"))
    parser.add_argument("--heights", type=float, nargs=2, metavar=("HMIN", "HMAX"))
    parser.add_argument("--tol", type=float, default=10.0, help="epipolar tolerance, px")
    parser.add_argument("--sigma", type=float, default=0.5, help="a priori sigma, px")
    parser.add_argument("-o", "--output", required=True, metavar="OBS.csv")
    parser.add_argument("--overwrite", action="store_true")
    parser.set_defaults(func=run)


def models_of(images: list[str], specs: list[str]):
    """Model per image: ``--model IMG=FILE`` or the RPC read from the image."""
    from ..io import read_rpc
    from . import CommandError

    given = {}
    for spec in specs:
        img, sep, path = spec.partition("=")
        if not sep or img not in images:
            raise CommandError(f"--model {spec!r}: expected IMG=RPCFILE with IMG one of the images")
        given[img] = path
    return [read_rpc(given.get(img, img)) for img in images]


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..io import Observations, refuse_existing, write_observations
    from ..stereo import guided_matches, los_heights, sift_features_raster
    from . import CommandError

    if len(args.images) < 2:
        raise CommandError("give at least two images")
    refuse_existing(args.output, args.overwrite)  # before any work
    models = models_of(args.images, args.model)
    names = [pathlib.Path(p).stem for p in args.images]
    if len(set(names)) != len(names):
        raise CommandError("image file names (stems) must differ: they name the images")
    feats = [
        sift_features_raster(p, args.roi if i == 0 else None) for i, p in enumerate(args.images)
    ]
    ids, imgs, xy = [], [], []
    for i in range(len(args.images)):
        for j in range(i + 1, len(args.images)):
            h_range = args.heights or los_heights(models[i])
            m = guided_matches(models[i], models[j], *feats[i], *feats[j], h_range, args.tol)
            print(
                f"{names[i]} - {names[j]}: {len(m)} matches ({m.n_candidates} before outlier "
                f"rejection), offset across the epipolar curve {np.median(m.across_px):+.3f} px"
                if len(m)
                else f"{names[i]} - {names[j]}: no match"
            )
            for k in range(len(m)):
                pid = f"{names[i]}_{names[j]}_{k}"
                ids += [pid, pid]
                imgs += [names[i], names[j]]
                xy += [m.xy1[k], m.xy2[k]]
    if not ids:
        raise CommandError("no tie point found")
    obs = Observations(
        tuple(ids), tuple(imgs), np.array(xy, dtype=float), np.full(len(ids), args.sigma)
    )
    write_observations(obs, args.output, overwrite=args.overwrite)
    print(f"wrote {len(ids) // 2} tie points to {args.output}")
    return 0
