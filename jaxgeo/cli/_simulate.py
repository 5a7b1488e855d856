"""``jaxgeo simulate``: write a simulated scene (vendor RPCs, truth, images) to a folder.

    jaxgeo simulate cartosat1 --seed S --out DIR [--site hobart|warsaw] [--gcps N] [--noise-px A]
    jaxgeo simulate carto2s-strip --scenes N --seed S --out DIR [--gcp-every K] [--noise-px A]
    jaxgeo simulate stereo-scene --size N --seed S [--jitter-px A] [--jitter-period-lines P]
                                 [--exact-rpc] [--relief-m M] [--site-seed S2]
                                 [--view-angle DEG] [--change DH EAST NORTH SIGMA] --out DIR
    (each also [--overwrite] [--quiet] [--json])

Existing files in DIR are never replaced unless ``--overwrite`` is given (checked before any
work; nothing is written then). ``cartosat1`` and ``carto2s-strip`` write files ready for
``jaxgeo adjust`` (RPC text files, ``ground.csv``, ``observations.csv``) with the truth in
``truth.json``. Parse -> a settings object (:class:`jaxgeo.simulate.Cartosat1Settings`,
``Carto2SStripSettings``, ``StereoSceneSettings``) -> one call (``write_cartosat1_stereo``,
``write_carto2s_strip``, ``stereo_scene``) -> print (``--json``: one JSON object).

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
Another date of the same site: --site-seed S2 (the ground of the scene of seed S2, seen by
this seed's images), --view-angle DEG (along-track view angle, default 11.3) and --change
DH EAST NORTH SIGMA (a Gaussian height change of DH m at EAST, NORTH m from the site's
centre, sigma SIGMA m: a landslide's bowl, a deposit).
"""

from __future__ import annotations

import argparse

from ._common import add_command, add_json, add_out, add_quiet

OPTIONS = {
    "seed": "--seed", "n_gcps": "--gcps", "site": "--site", "image_noise_px": "--noise-px",
    "n_scenes": "--scenes", "gcp_every": "--gcp-every", "size": "--size",
    "jitter_px": "--jitter-px", "jitter_period_lines": "--jitter-period-lines",
    "exact_rpc": "--exact-rpc", "relief_m": "--relief-m", "site_seed": "--site-seed",
    "view_angle_deg": "--view-angle", "height_m": "--change", "east_m": "--change",
    "north_m": "--change", "sigma_m": "--change",
}  # fmt: skip
"""The option of each setting the command sets (errors name the option, not the field)."""
CARTOSAT1 = ("Write a simulated Cartosat-1 fore/aft pair (000_, 002_) into DIR: fore.txt, "
             "aft.txt (vendor RPCs), ground.csv, observations.csv, truth.json.")  # fmt: skip
STRIP = ("Write a simulated Carto-2S strip of N sub-scenes (003_) into DIR: scene_000.txt ... "
         "(vendor RPCs), ground.csv, observations.csv, strip.json, truth.json.")  # fmt: skip


def register(sub) -> None:
    line = "write a simulated Cartosat-1 pair, Carto-2S strip or rendered stereo scene"
    parser = add_command(sub, "simulate", line, __doc__)
    kinds = parser.add_subparsers(dest="kind", required=True, metavar="KIND")

    def kind(name: str, help: str, doc: str, noise: bool = True) -> argparse.ArgumentParser:
        p = add_command(kinds, name, help, doc)
        p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
        add_out(p, "DIR", "output folder (created if missing)")
        if noise:
            p.add_argument("--noise-px", type=float, default=0.3,
                           help="image noise std (px, default 0.3)")  # fmt: skip
        add_quiet(p)
        add_json(p)
        p.set_defaults(func=run)
        return p

    p = kind("cartosat1", "Cartosat-1 fore/aft stereo pair (fore.txt, aft.txt)", CARTOSAT1)
    p.add_argument("--site", choices=("hobart", "warsaw"), default="hobart",
                   help="hobart: 69 points in one quarter, 0..1260 m; warsaw: 36 spread, "
                   "flat")  # fmt: skip
    p.add_argument("--gcps", type=int, default=9, help="number of GCPs (rest: check points)")

    p = kind("carto2s-strip", "Carto-2S strip of sub-scenes (scene_000.txt ...)", STRIP)
    p.add_argument("--scenes", type=int, default=80, help="number of sub-scenes (default 80)")
    p.add_argument("--gcp-every", type=int, default=4, help="GCPs in every K-th scene (default 4)")

    p = kind("stereo-scene", "rendered Pleiades-like stereo pair with RPCs and truth (left.tif, "
             "right.tif, truth_dsm.tif, truth.json)", __doc__.split("\n\n")[3],
             noise=False)  # fmt: skip
    p.add_argument("--size", type=int, required=True, metavar="N", help="image size, N x N px")
    p.add_argument("--jitter-px", type=float, default=0.0, metavar="A",
                   help="amplitude (px) of a sinusoidal attitude jitter of the true models, "
                   "across track (along track a quarter of it); the delivered RPCs are fitted "
                   "without it (default 0)")  # fmt: skip
    p.add_argument("--jitter-period-lines", type=float, default=1000.0, metavar="P",
                   help="period of the jitter in image lines (default 1000)")  # fmt: skip
    p.add_argument("--exact-rpc", action="store_true",
                   help="deliver RPCs fitted to the exact (jitter-free) true models, not to a "
                   "copy with a few pixels of pointing error")  # fmt: skip
    p.add_argument("--relief-m", type=float, metavar="M",
                   help="terrain relief in metres (default: a tenth of the footprint, "
                   "30..300 m)")  # fmt: skip
    p.add_argument("--site-seed", type=int, metavar="S2",
                   help="another date of a site: the terrain and texture of the scene of seed "
                   "S2 (same --size and --relief-m), seen by the images of --seed")  # fmt: skip
    p.add_argument("--view-angle", type=float, default=11.3, metavar="DEG",
                   help="along-track view angle of the pair, left +DEG, right -DEG (default "
                   "11.3: base/height 0.45)")  # fmt: skip
    p.add_argument("--change", type=float, nargs=4, metavar=("DH", "EAST", "NORTH", "SIGMA"),
                   help="a height change of the ground on this date: a Gaussian bump of DH m "
                   "(< 0: a bowl) at EAST, NORTH m from the site's centre, sigma SIGMA "
                   "m")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    import pathlib
    import time

    from ..simulate import SimulationError
    from . import CommandError
    from ._common import note, print_json

    out = pathlib.Path(args.out)
    if out.exists() and not out.is_dir():
        raise CommandError(f"--out {out}: exists and is not a directory")
    _check_sizes(args)
    start = time.perf_counter()
    try:
        summary, lines = _simulate(args, out, note)
    except SimulationError as err:
        raise CommandError(err.render(OPTIONS)) from None
    summary["total_s"] = round(time.perf_counter() - start, 2)
    if args.json:
        print_json(summary)
    else:
        if args.kind == "stereo-scene":
            print(f"wrote {', '.join(summary['files'])} to {out} in {summary['total_s']:.1f} s")
        else:
            print(f"wrote {len(summary['files'])} files to {out}")
        print("\n".join(lines))
    return 0


def _simulate(args: argparse.Namespace, out, note) -> tuple[dict, list[str]]:
    """Build the settings, make the one library call: ``(the JSON summary, the human lines)``."""
    from .. import simulate as sim
    from ..simulate.internal import stereo_scene_files

    head = {"kind": args.kind, "out": str(out), "seed": args.seed}
    if args.kind == "cartosat1":
        settings = sim.Cartosat1Settings(site=args.site, n_gcps=args.gcps,
                                         image_noise_px=args.noise_px)  # fmt: skip
        note(f"simulating a Cartosat-1 pair over {args.site} (seed {args.seed})", args.quiet)
        scene = sim.write_cartosat1_stereo(out, args.seed, settings, overwrite=args.overwrite)
        acc, files = scene.accuracy(), scene.files(out)
        img = ", ".join(f"{n} {v['rms']:.1f} px" for n, v in acc["image_px"].items())
        inter = acc["intersection_m"]
        summary = {**head, "files": [p.name for p in files], "site": args.site,
                   "points": len(scene.ground), "gcps": args.gcps,
                   "vendor_accuracy": acc}  # fmt: skip
        return summary, [f"vendor RPC direct georeferencing: {img}; forward intersection "
                         f"{inter['rms_plan']:.1f} m planimetry, "
                         f"{inter['rms_h']:.1f} m height"]  # fmt: skip
    if args.kind == "carto2s-strip":
        settings = sim.Carto2SStripSettings(gcp_every=args.gcp_every,
                                            image_noise_px=args.noise_px)  # fmt: skip
        note(f"simulating a Carto-2S strip of {args.scenes} sub-scenes (seed {args.seed})",
             args.quiet)  # fmt: skip
        strip = sim.write_carto2s_strip(out, args.scenes, args.seed, settings,
                                        overwrite=args.overwrite)  # fmt: skip
        acc = strip.accuracy()
        summary = {**head, "files": [p.name for p in strip.files(out)], "scenes": args.scenes,
                   "points": len(strip.ground), "observations": len(strip.observations),
                   "vendor_rms_px": {"min": acc["rms_min"], "max": acc["rms_max"]}}  # fmt: skip
        return summary, [f"vendor RPC direct georeferencing: {acc['rms_min']:.1f} .. "
                         f"{acc['rms_max']:.1f} px RMS per sub-scene"]  # fmt: skip
    change = None if args.change is None else sim.TerrainChange(*args.change)
    settings = sim.StereoSceneSettings(jitter_px=args.jitter_px, exact_rpc=args.exact_rpc,
                                       jitter_period_lines=args.jitter_period_lines,
                                       relief_m=args.relief_m, site_seed=args.site_seed,
                                       view_angle_deg=args.view_angle,
                                       change=change)  # fmt: skip
    note(f"simulating a {args.size} x {args.size} px stereo scene (seed {args.seed})", args.quiet)
    scene = sim.stereo_scene(out, args.size, args.seed, settings, overwrite=args.overwrite,
                             progress=not args.quiet)  # fmt: skip
    info, dsm = scene.info, scene.dsm
    fit = {n: info["rpc_fit"][n]["check_max_px"] for n in info["rpc_fit"]}
    vs = {n: info["rpc_vs_truth"][n] for n in info["rpc_vs_truth"]}
    summary = {
        **head,
        "files": [p.name for p in stereo_scene_files(out)],
        "size": args.size,
        "gsd_m": info["gsd_m"],
        "base_to_height": info["base_to_height"],
        "relief_m": info["params"]["relief_m"],
        "jitter_px": args.jitter_px,
        "site_seed": args.site_seed,
        "view_angle_deg": args.view_angle,
        "change": info["params"].get("change"),
        "rpc_fit_check_max_px": fit,
        "rpc_vs_truth_rms_px": {n: v["nojitter_px"]["rms"] for n, v in vs.items()},
        "rpc_vs_jittered_truth_rms_px": {n: v["jittered_px"]["rms"] for n, v in vs.items()},
        "dsm_shape": [dsm.rows, dsm.cols],
        "dsm_res_m": dsm.res_m,
        "models_s": round(info["seconds"]["models"], 2),
    }
    what = "the exact models" if args.exact_rpc else "the vendor's models (pointing error)"
    lines = [f"GSD {info['gsd_m']:.3f} m, base/height {info['base_to_height']:.2f}, relief "
             f"{info['params']['relief_m']:.0f} m, truth DSM {dsm.rows} x {dsm.cols} cells of "
             f"{dsm.res_m} m (EPSG:{dsm.epsg})",
             f"RPCs fitted without the jitter to {what}:"]  # fmt: skip
    lines += [f"  {n}: fit error {fit[n]:.1e} px max (check grid); RPC minus the jitter-free "
              f"true model {vs[n]['nojitter_px']['rms']:.2g} px RMS, minus the jittered one "
              f"{vs[n]['jittered_px']['rms']:.2g} px RMS (truth points)" for n in fit]  # fmt: skip
    return summary, lines


MAX_SCENES = 1000
"""``--scenes`` at most: twelve times the 80 sub-scenes of 003_'s strip."""
SCENE_BYTES_PER_PX = 50
"""Memory of ``stereo-scene`` per image pixel, measured: 470 MB at 512 px, 510 MB at 1024 px."""


def _check_sizes(args: argparse.Namespace) -> None:
    """A strip or a scene this machine cannot hold refused before any work (named by option)."""
    import os

    from ._common import in_range

    if args.kind == "carto2s-strip":
        in_range("--scenes", args.scenes, 1, MAX_SCENES)
    if args.kind == "stereo-scene":
        try:
            ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError, AttributeError):  # no sysconf (Windows): no bound
            return
        side = int((ram / SCENE_BYTES_PER_PX) ** 0.5)
        why = f" (about {SCENE_BYTES_PER_PX} bytes per pixel; this machine has {ram / 1e9:.0f} GB)"
        in_range("--size", args.size, None, side, "px", why=why)
