"""``jaxgeo demo``: direct georeferencing vs bias-corrected adjustment on the embedded scene.

The packaged scene (``jaxgeo/data/cartosat1_demo``) is a simulated Cartosat-1 fore/aft pair over
a Hobart-like site whose vendor RPCs are biased by tens of pixels, with 9 GCPs and 60 check
points, as in section 4.2 of 000_5aba1cb50921f3c6.txt. The demo intersects the check points
with the vendor RPCs (table 3), then adjusts the RPCs with an image-space bias per image and
the GCPs (table 4), and prints both reports side by side.
"""

from __future__ import annotations

import argparse
import dataclasses


def register(sub) -> None:
    from ..models.internal import BIAS_KINDS
    from ._common import add_command, add_json, add_quiet

    parser = add_command(
        sub,
        "demo",
        "direct georeferencing vs bias-corrected adjustment on the embedded scene",
        __doc__,
        {1: "the adjustment did not converge (the last state is reported)"},
    )
    parser.add_argument(
        "--bias",
        choices=tuple(BIAS_KINDS),
        default="affine",
        help="bias model of the adjustment (default affine)",
    )
    add_json(parser)
    add_quiet(parser)  # (the demo shows no progress: accepted like every command's)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import time

    from ..bundle import adjust_files
    from ..bundle.internal import format_reports
    from ..simulate import demo_dir
    from ._common import print_json

    folder = demo_dir()
    t0 = time.perf_counter()
    run = adjust_files(
        {"fore": folder / "fore.txt", "aft": folder / "aft.txt"},
        folder / "observations.csv",
        folder / "ground.csv",
        bias=args.bias,
        direct_roles=("check",),
    )
    seconds = time.perf_counter() - t0
    result, d, a = run.result, run.direct, run.result.report
    if args.json:
        data = run.summary()
        data["seconds"] = seconds
        print_json(data)
        return 0 if result.converged else 1
    roles = result.point_role
    n_gcp, n_chk = roles.count("gcp"), roles.count("check")
    plan = lambda r: float((r.rms_m[0] ** 2 + r.rms_m[1] ** 2) ** 0.5)  # noqa: E731
    print(
        f"Simulated Cartosat-1 stereo pair (fore/aft, 2.5 m GSD), {n_gcp} GCPs, "
        f"{n_chk} check points; data in {folder}"
    )
    print()
    d = dataclasses.replace(d, title="direct (vendor RPCs)")
    a = dataclasses.replace(a, title=f"adjusted ({args.bias} bias)")
    print(format_reports([d, a]))
    print()
    print(
        f"check points: {plan(d):.1f} m planimetry / {d.rms_m[2]:.1f} m height with the vendor "
        f"RPCs -> {plan(a):.2f} m / {a.rms_m[2]:.2f} m after bias-corrected adjustment "
        f"({result.num_steps} LM steps, s0 = {result.s0:.2f}; {seconds:.1f} s incl. compilation)"
    )
    return 0 if result.converged else 1
