"""``jaxgeo adjust``: bundle block adjustment of RPC images with bias compensation.

    jaxgeo adjust --image NAME=RPCFILE [--image ...] --ground GROUND.csv
                  --observations OBS.csv --bias {none,shift,shift-drift,affine}
                  [--json] [--out DIR] [--overwrite]

GROUND.csv: ``id,lon,lat,h,role[,sigma_e_m,sigma_n_m,sigma_h_m]`` (role gcp or check);
OBS.csv: ``id,image,x,y[,sigma_px]``; points in OBS but not in GROUND are tie points. The
report compares direct georeferencing (forward intersection with the given RPCs, no GCP) with
the adjustment, as tables 3 and 4 of 000_5aba1cb50921f3c6.txt. ``--out DIR`` writes the
adjusted models (RPC files with the bias folded in, and a JSON with RPC + bias + sigmas), the
adjusted points, the residuals and the report; inputs and existing files are never replaced
(``--overwrite`` allows replacing earlier outputs, never the inputs).
"""

from __future__ import annotations

import argparse

BIASES = ("none", "shift", "shift-drift", "affine")


def register(sub) -> None:
    parser = sub.add_parser(
        "adjust",
        help="bundle block adjustment of RPC images (bias compensation)",
        description=__doc__.split("\n\n")[0],
    )
    parser.add_argument(
        "--image",
        action="append",
        required=True,
        metavar="NAME=RPCFILE",
        help="an image name (as in OBS.csv) and its RPC file; repeat per image",
    )
    parser.add_argument("--ground", metavar="GROUND.csv", help="GCPs and check points")
    parser.add_argument(
        "--observations", required=True, metavar="OBS.csv", help="image measurements"
    )
    parser.add_argument(
        "--bias",
        choices=BIASES,
        default="affine",
        help="image-space bias model adjusted per image (default affine)",
    )
    parser.add_argument(
        "--method",
        choices=("lm", "gn"),
        default="lm",
        help="Levenberg-Marquardt (default) or Gauss-Newton",
    )
    parser.add_argument(
        "--loss",
        choices=("l2", "huber", "cauchy"),
        default="l2",
        help="robust loss on image observations (default l2)",
    )
    parser.add_argument("--max-steps", type=int, default=50, help="solver steps (default 50)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--out", metavar="DIR", help="write adjusted models and the report here")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace earlier outputs in --out (never the inputs)",
    )
    parser.set_defaults(func=run)


def _images(specs: list[str]) -> dict[str, str]:
    from . import CommandError

    out: dict[str, str] = {}
    for spec in specs:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path:
            raise CommandError(f"--image {spec!r}: expected NAME=RPCFILE")
        if name in out:
            raise CommandError(f"--image {name!r} given twice")
        out[name] = path
    return out


def summary(result, direct, bias: str) -> dict:
    """The JSON object of ``jaxgeo adjust --json`` (and ``report.json``)."""
    rep = result.report.to_dict() if result.report is not None else None
    empty = {"n": 0, "rms_m": [None] * 3, "min_m": [None] * 3, "max_m": [None] * 3}
    images = {}
    for name in result.models:
        rms = rep["images"].get(name, {}).get("rms_px", [None, None]) if rep else [None, None]
        own = result.parameters(name)
        images[name] = {
            "rms_px": rms,
            "params": {k: v for k, (v, _) in own.items()},
            "sigmas": {k: s for k, (_, s) in own.items()},
        }
    s0 = result.s0 if result.s0 == result.s0 else None
    blunders = [
        {"id": p, "image": img, "w": [float(x) for x in w]}
        for p, img, w, b in zip(
            result.observation_ids,
            result.observation_images,
            result.standardized,
            result.blunders,
            strict=True,
        )
        if b
    ]
    return {
        "bias": bias,
        "s0": s0,
        "redundancy": result.redundancy,
        "converged": result.converged,
        "message": result.message,
        "num_steps": result.num_steps,
        "checkpoints": rep["checkpoints"] if rep else empty,
        "images": images,
        "blunders": blunders,
        "direct": direct.to_dict() if direct is not None else None,
    }


def text_report(result, direct, bias: str) -> str:
    from ..adjust import format_reports

    lines = [
        f"bundle adjustment ({bias} bias): {result.message} in {result.num_steps} steps, "
        f"s0 = {result.s0:.3f}, redundancy {result.redundancy}"
    ]
    reports = [r for r in (direct, result.report) if r is not None]
    if reports:
        lines += ["", format_reports(reports)]
    lines += ["", "adjusted parameters (a posteriori sigma):"]
    for name, value, sigma in zip(
        result.param_names, result.params, result.param_sigma, strict=True
    ):
        lines.append(f"  {name:<32} {value: .6g} +- {sigma:.2g}")
    flagged = [
        f"{p}@{img}"
        for p, img, b in zip(
            result.observation_ids, result.observation_images, result.blunders, strict=True
        )
        if b
    ]
    if flagged:
        lines.append(f"possible blunders (|w| > k): {', '.join(flagged)}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import json
    import sys
    import warnings

    from ..adjust import AdjustmentError, NotConvergedWarning, adjust, direct_georeferencing
    from ..adjust.export import write_outputs
    from ..io import read_rpc
    from ..io.tables import read_ground, read_observations
    from . import CommandError

    paths = _images(args.image)
    models = {name: read_rpc(path) for name, path in paths.items()}
    obs = read_observations(args.observations)
    ground = read_ground(args.ground) if args.ground else None
    if args.max_steps < 1:
        raise CommandError(f"--max-steps must be >= 1, got {args.max_steps}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = adjust(
                models,
                obs,
                ground,
                bias=args.bias,
                method=args.method,
                loss=args.loss,
                max_steps=args.max_steps,
            )
        except AdjustmentError as err:
            raise CommandError(str(err)) from None
    direct = None
    if ground is not None and len(models) >= 2:
        direct = direct_georeferencing(models, obs, ground)
    for w in caught:
        prefix = "warning" if issubclass(w.category, NotConvergedWarning) else "note"
        print(f"jaxgeo adjust: {prefix}: {w.message}", file=sys.stderr)
    data = summary(result, direct, args.bias)
    text = text_report(result, direct, args.bias)
    if args.out:
        inputs = [*paths.values(), args.observations] + ([args.ground] if args.ground else [])
        written = write_outputs(args.out, result, text, data, inputs, overwrite=args.overwrite)
        data["written"] = [str(p) for p in written]
    if args.json:
        print(json.dumps(data, indent=1))
    else:
        print(text)
        if args.out:
            print(f"\nwrote {len(data['written'])} files to {args.out}")
    return 0 if result.converged else 1
