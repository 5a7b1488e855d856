"""``jaxgeo strip``: two-level full-strip adjustment of the sub-scenes of a strip (003_).

    jaxgeo strip STRIP [--ground CSV] [--observations CSV] [--ties-per-pair N]
                 [--tie-height M | --dem FILE] [--bias affine|shift-drift|shift]
                 [--degree quadratic|affine|shift] [--json] [--out DIR [--rpc-format txt|rpb]]
                 [--overwrite]

STRIP is a folder holding ``strip.json`` (or the json file itself; see
:func:`jaxgeo.strip.read_strip`) with the sub-scenes' vendor RPCs, ``ground.csv`` and
``observations.csv`` beside it, as ``jaxgeo simulate carto2s-strip`` writes them. Level 1 forms
tie points in the overlaps of adjacent sub-scenes and bundle-adjusts an image bias per
sub-scene with the ties and the GCPs; level 2 fits one universal lat/lon correction to the GCPs
and applies it to every sub-scene (003_a7d3ea260371d8c5.txt sections 6-9). The report gives,
per sub-scene, the check-point RMS (east/north m) of the vendor RPCs (``direct``), after level 1
and after level 2, and per adjacent pair the gap between a tie localised in one sub-scene and in
the other. ``--out DIR`` writes one RPC per sub-scene refitted to its final model
(``NAME_RPC.TXT`` or ``NAME.RPB``), ``report.json`` and ``report.txt``; every destination is
checked before anything is written, inputs are never replaced and existing files only with
``--overwrite``.
"""

from __future__ import annotations

import argparse
import math

BIASES = ("affine", "shift-drift", "shift")
DEGREES = ("quadratic", "affine", "shift", "none", "auto")
TERMS = ("1", "lat", "lon", "lat^2", "lon^2", "lat*lon")
REFIT_WARN_PX = 0.01
"""An RPC refit whose check-grid error exceeds this (px) is reported on stderr."""


def register(sub) -> None:
    parser = sub.add_parser(
        "strip",
        help="two-level full-strip adjustment of a Carto-2S-style strip of sub-scenes",
        description=__doc__.split("\n\n")[0],
    )
    parser.add_argument("strip", metavar="STRIP", help="strip folder or its strip.json")
    parser.add_argument("--ground", metavar="CSV", help="GCPs/check points (default ground.csv)")
    parser.add_argument(
        "--observations", metavar="CSV", help="image measurements (default observations.csv)"
    )
    ties = parser.add_argument_group("level 1: tie points and biases")
    ties.add_argument(
        "--ties-per-pair",
        type=int,
        default=50,
        metavar="N",
        help="ties formed per adjacent pair (default 50)",
    )
    ties.add_argument(
        "--tie-margin-px",
        type=float,
        default=None,
        metavar="PX",
        help="ties kept this far inside each overlap (px, default 100)",
    )
    ties.add_argument(
        "--tie-sigma-px",
        type=float,
        default=None,
        metavar="PX",
        help="a priori tie sigma (px, default 0.1)",
    )
    height = ties.add_mutually_exclusive_group()
    height.add_argument(
        "--tie-height",
        type=float,
        metavar="M",
        help="one ellipsoidal height (m) for all ties (default: mean GCP/check height)",
    )
    height.add_argument(
        "--dem",
        metavar="FILE",
        help="tie heights from a single-band DEM raster (ellipsoidal m, any CRS)",
    )
    ties.add_argument(
        "--dem-offset-m",
        type=float,
        default=0.0,
        metavar="N",
        help="added to the DEM heights (e.g. the geoid undulation for orthometric DEMs)",
    )
    ties.add_argument(
        "--tie-height-sigma-m",
        type=float,
        default=None,
        metavar="M",
        help="sigma of the tie height priors (m, default 500; smaller with a good --dem)",
    )
    ties.add_argument(
        "--bias",
        choices=BIASES,
        default="affine",
        help="image bias adjusted per sub-scene (default affine, as in 003_)",
    )
    ties.add_argument(
        "--ties-only-level1",
        action="store_true",
        help="level 1 sees the ties only (the GCPs enter at level 2); needs the bias priors",
    )
    ties.add_argument(
        "--bias-prior-shift-px",
        type=float,
        metavar="S",
        help="prior sigma (px) of every sub-scene's bias shift",
    )
    ties.add_argument(
        "--bias-prior-matrix",
        type=float,
        metavar="X",
        help="prior sigma (px/px) of the affine matrix (or shift-drift drift) terms",
    )
    ties.add_argument("--method", choices=("lm", "gn"), default="lm", help="level-1 solver")
    ties.add_argument(
        "--max-steps", type=int, default=50, metavar="N", help="level-1 solver steps (50)"
    )
    parser.add_argument(
        "--degree",
        choices=DEGREES,
        default="quadratic",
        help="level 2: the universal correction (default quadratic, eq. 12-13 of 003_; auto: "
        "the degree that best predicts each GCP scene left out)",
    )
    out = parser.add_argument_group("output")
    out.add_argument("--json", action="store_true", help="print one JSON object")
    out.add_argument("--out", metavar="DIR", help="write the updated RPCs and the report here")
    out.add_argument(
        "--rpc-format",
        choices=("txt", "rpb"),
        default="txt",
        help="updated RPC files as NAME_RPC.TXT (default) or NAME.RPB",
    )
    out.add_argument(
        "--rpc-grid",
        type=int,
        nargs=3,
        default=(21, 21, 7),
        metavar=("NX", "NY", "NH"),
        help="RPC refit grid: columns, rows, height layers (default 21 21 7)",
    )
    out.add_argument(
        "--overwrite", action="store_true", help="replace earlier outputs (never the inputs)"
    )
    parser.set_defaults(func=run)


def _check_args(args: argparse.Namespace) -> None:
    from . import CommandError

    if args.ties_per_pair < 1:
        raise CommandError(f"--ties-per-pair must be >= 1, got {args.ties_per_pair}")
    if args.max_steps < 1:
        raise CommandError(f"--max-steps must be >= 1, got {args.max_steps}")
    if min(args.rpc_grid) < 4:
        raise CommandError(f"--rpc-grid needs at least 4 points per axis, got {args.rpc_grid}")
    positive = {
        "--tie-sigma-px": args.tie_sigma_px,
        "--tie-height-sigma-m": args.tie_height_sigma_m,
        "--bias-prior-shift-px": args.bias_prior_shift_px,
        "--bias-prior-matrix": args.bias_prior_matrix,
    }
    for flag, value in positive.items():
        if value is not None and not (value > 0 and math.isfinite(value)):
            raise CommandError(f"{flag} must be a positive number, got {value}")
    finite = {"--tie-margin-px": args.tie_margin_px, "--tie-height": args.tie_height,
              "--dem-offset-m": args.dem_offset_m}  # fmt: skip
    for flag, value in finite.items():
        if value is not None and not math.isfinite(value):
            raise CommandError(f"{flag} must be finite, got {value}")
    if args.tie_margin_px is not None and args.tie_margin_px < 0:
        raise CommandError(f"--tie-margin-px must be >= 0, got {args.tie_margin_px}")
    if args.dem_offset_m and not args.dem:
        raise CommandError("--dem-offset-m applies to --dem heights only")
    if args.bias_prior_matrix is not None and args.bias == "shift":
        raise CommandError("--bias-prior-matrix: the shift bias has no matrix terms")
    if args.ties_only_level1:
        need = ["--bias-prior-shift-px"] if args.bias_prior_shift_px is None else []
        if args.bias != "shift" and args.bias_prior_matrix is None:
            need.append("--bias-prior-matrix")
        if need:
            raise CommandError(
                f"--ties-only-level1 needs {' and '.join(need)}: ties fix the differences of the "
                "sub-scene biases, not their common part"
            )


def bias_prior(args: argparse.Namespace, rpc):
    """The level-1 bias prior sigmas as a pytree like the biased model (``None``: no prior)."""
    if args.bias_prior_shift_px is None and args.bias_prior_matrix is None:
        return None
    import equinox as eqx
    import jax
    import numpy as np

    from ..adjust.solve import with_bias

    proto = with_bias({"scene": rpc}, args.bias)["scene"]
    sigma = jax.tree.map(lambda x: np.full(np.shape(x), np.inf), proto)
    if args.bias_prior_shift_px is not None:
        sigma = eqx.tree_at(lambda m: m.bias.shift_px, sigma, np.full(2, args.bias_prior_shift_px))
    if args.bias_prior_matrix is not None:
        field = "matrix" if args.bias == "affine" else "drift"
        sigma = eqx.tree_at(
            lambda m: getattr(m.bias, field),
            sigma,
            np.full(np.shape(getattr(proto.bias, field)), args.bias_prior_matrix),
        )
    return sigma


def strip_paths(args: argparse.Namespace):
    """``(strip.json, ground, observations, RPC files)`` of the STRIP argument."""
    import json
    import pathlib

    path = pathlib.Path(args.strip)
    if path.is_dir():
        path = path / "strip.json"
    ground = pathlib.Path(args.ground) if args.ground else path.parent / "ground.csv"
    obs = pathlib.Path(args.observations) if args.observations else path.parent / "observations.csv"
    try:  # called after read_strip succeeded: the layout is known to be valid
        scenes = json.loads(path.read_text())["scenes"]
        rpcs = [path.parent / str(e["rpc"]) for e in scenes]
    except (OSError, ValueError, KeyError, TypeError):
        rpcs = []
    return path, ground, obs, rpcs


def _finite(value):
    """JSON-safe copy: non-finite floats -> ``None``, numpy scalars/arrays -> Python."""
    import numpy as np

    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def summary(result, strip_json, rpc_fits=None) -> dict:
    """The JSON object of ``jaxgeo strip --json`` (and ``report.json``): the options, the GCP
    distribution check, the report (:meth:`~jaxgeo.strip.StripReport.to_dict`), the universal
    correction, per sub-scene (``models``) the level-1 bias with a posteriori sigmas and, given
    ``rpc_fits``, the refit error of its updated RPC (px); non-finite numbers become ``null``."""
    import numpy as np

    corr = result.correction
    dist = result.distribution
    names = result.strip.names
    models = {}
    for name in names:
        own = result.level1.parameters(name)
        models[name] = {
            "bias": {k: v for k, (v, _) in own.items()},
            "bias_sigma": {k: s for k, (_, s) in own.items()},
        }
        if rpc_fits is not None and name in rpc_fits:
            rep = rpc_fits[name]
            models[name]["rpc_refit_px"] = {
                "fit_rms": rep.fit_rms_px,
                "check_rms": rep.check_rms_px,
                "check_max": rep.check_max_px,
                "h_range_m": list(rep.h_range_m),
            }
    coeffs = np.asarray(corr.coeffs)
    data = {
        "strip": str(strip_json),
        "options": dict(result.options),
        "distribution": {
            "ok": dist.ok,
            "gcp_scenes": [names[k] for k in dist.gcp_scenes],
            "gaps": [[names[lo], names[hi]] for lo, hi in dist.gaps],
            "missing_head": dist.missing_head,
            "missing_tail": dist.missing_tail,
            "message": dist.message(names),
        },
        "report": result.report.to_dict(),
        "correction": {
            "degree": result.options["degree"],
            "terms": list(TERMS),
            "normalisation": "lat_n = (lat - offset[0]) / scale[0], lon_n = (lon - offset[1]) "
            "/ scale[1]; dlat, dlon in degrees",
            "dlat_deg": coeffs[0].tolist(),
            "dlon_deg": coeffs[1].tolist(),
            "offset_latlon_deg": np.asarray(corr.offset).tolist(),
            "scale_latlon_deg": np.asarray(corr.scale).tolist(),
        },
        "models": models,
        "timings_s": dict(result.timings_s),
    }
    return _finite(data)


def text_report(result) -> str:
    import numpy as np

    o = result.options
    lines = [
        f"full-strip adjustment: {len(result.strip.names)} sub-scenes, level 1 {o['bias']} bias "
        f"per sub-scene ({'ties only' if not o['level1_gcps'] else 'ties + GCPs'}, "
        f"{o['ties_per_pair']} ties per pair), level 2 {o['degree']} universal correction",
        "",
        result.report.format(),
        "",
        f"universal correction (degrees; terms {', '.join(TERMS)} of normalised lat, lon):",
    ]
    for label, row in zip(("dlat", "dlon"), np.asarray(result.correction.coeffs), strict=True):
        lines.append(f"  {label} " + " ".join(f"{c: .3e}" for c in row))
    t = result.timings_s
    setup, solve = t.get("setup", 0.0), t.get("first_call", 0.0)
    lines.append(f"time: setup {setup:.1f} s, both levels {solve:.1f} s (including compilation)")
    return "\n".join(lines)


def _destinations(args, names, inputs) -> dict:
    """Output path per file name; refuses inputs and (without --overwrite) existing files."""
    import pathlib

    from . import CommandError

    out = pathlib.Path(args.out)
    if out.exists() and not out.is_dir():
        raise CommandError(f"--out {out}: exists and is not a directory")
    suffix = "_RPC.TXT" if args.rpc_format == "txt" else ".RPB"
    files = [f"{n}{suffix}" for n in names] + ["report.json", "report.txt"]
    targets = {f: (out / f).resolve() for f in files}
    given = {pathlib.Path(p).resolve() for p in inputs}
    for path in targets.values():
        if path in given:
            raise CommandError(f"{path}: refusing to write an output over an input")
    existing = [str(p) for p in targets.values() if p.exists()]
    if existing and not args.overwrite:
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise CommandError(
            f"{existing[0]}{more}: exists; refusing to overwrite (choose another --out or pass "
            "--overwrite)"
        )
    return targets


def run(args: argparse.Namespace) -> int:
    import json
    import sys
    import warnings

    from ..adjust import AdjustmentError
    from ..io import read_dem, write_rpb, write_rpc_text
    from ..io.atomic import atomic_write_text
    from ..strip import GCPDistributionWarning, adjust_strip, read_strip
    from ..strip.solve import UniversalCorrectionWarning
    from . import CommandError

    _check_args(args)
    strip = read_strip(args.strip, args.ground, args.observations)
    strip_json, ground, obs, rpc_files = strip_paths(args)
    inputs = [strip_json, ground, obs, *rpc_files] + ([args.dem] if args.dem else [])
    targets = _destinations(args, strip.names, inputs) if args.out else None  # before the work
    if args.dem:
        tie_height = read_dem(args.dem, offset_m=args.dem_offset_m)
        if tie_height.vertical_crs and not args.dem_offset_m:
            print(f"jaxgeo strip: note: {args.dem} declares vertical CRS "
                  f"{tie_height.vertical_crs!r}; heights are used as ellipsoidal",
                  file=sys.stderr)  # fmt: skip
    else:
        tie_height = args.tie_height
    options = {
        k: v
        for k, v in dict(
            tie_margin_px=args.tie_margin_px,
            tie_sigma_px=args.tie_sigma_px,
            tie_height_sigma_m=args.tie_height_sigma_m,
        ).items()
        if v is not None
    }
    prior = bias_prior(args, strip.rpcs[strip.names[0]])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = adjust_strip(
                strip,
                ties_per_pair=args.ties_per_pair,
                tie_height=tie_height,
                bias=args.bias,
                bias_prior_sigma=prior,
                level1_gcps=not args.ties_only_level1,
                degree=args.degree,
                method=args.method,
                max_steps=args.max_steps,
                **options,
            )
        except AdjustmentError as err:
            raise CommandError(f"level-1 bundle adjustment of {strip_json}: {err}") from None
        except ValueError as err:
            msg = str(err)
            if "universal correction" in msg:  # too few / aligned GCPs: name the file, the flag
                msg = msg.replace("the affine (3) or shift (1) degree",
                                  "--degree affine (3) or --degree shift (1)")  # fmt: skip
                raise CommandError(f"{ground}: {msg}") from None
            raise
        finally:  # the GCP distribution warning matters most when the adjustment fails
            for w in caught:
                warns = (GCPDistributionWarning, UniversalCorrectionWarning)
                kind = "warning" if issubclass(w.category, warns) else "note"
                print(f"jaxgeo strip: {kind}: {w.message}", file=sys.stderr)
    converged = bool(result.report.strip["converged"])
    if not converged:
        print("jaxgeo strip: warning: the level-1 bundle adjustment did not converge",
              file=sys.stderr)  # fmt: skip
    text = text_report(result)
    fits = None
    written = []
    if targets is not None:
        updated = result.updated_rpcs(grid=tuple(args.rpc_grid))
        fits = {name: rep for name, (_, rep) in updated.items()}
        worst = max(fits, key=lambda n: fits[n].check_max_px)
        if fits[worst].check_max_px > REFIT_WARN_PX:
            print(f"jaxgeo strip: warning: the refitted RPC of {worst} differs from its adjusted "
                  f"model by up to {fits[worst].check_max_px:.3g} px on the check grid",
                  file=sys.stderr)  # fmt: skip
        data = summary(result, strip_json, fits)
        suffix = "_RPC.TXT" if args.rpc_format == "txt" else ".RPB"
        refit = "\n".join(
            f"{n}{suffix}: RPC refitted to the final model, RMS {r.check_rms_px:.2g} px, max "
            f"{r.check_max_px:.2g} px on the check grid"
            for n, r in fits.items()
        )
        write = write_rpc_text if args.rpc_format == "txt" else write_rpb
        for name, (rpc, _) in updated.items():
            written.append(write(rpc, targets[f"{name}{suffix}"], overwrite=args.overwrite))
        data["written"] = [str(p) for p in [*written, targets["report.json"],
                                            targets["report.txt"]]]  # fmt: skip
        written.append(atomic_write_text(targets["report.json"], json.dumps(data, indent=1) + "\n",
                                         overwrite=args.overwrite))  # fmt: skip
        written.append(atomic_write_text(targets["report.txt"], f"{text}\n\n{refit}\n",
                                         overwrite=args.overwrite))  # fmt: skip
    else:
        data = summary(result, strip_json)
    if args.json:
        print(json.dumps(data, indent=1))
    else:
        print(text)
        if args.out:
            worst = max(r.check_max_px for r in fits.values())
            print(f"\nwrote {len(written)} files to {args.out} (updated RPCs: refit error "
                  f"<= {worst:.2g} px on the check grid)")  # fmt: skip
    return 0 if converged else 1
