"""What the commands read, given the same way everywhere: images (``--model IMG=FILE`` with IMG
the path, file name or stem, ``--image-origin``), the DEM (``--dem``, ``--dem-height``,
``--geoid``, ``--dem-band``, ``--dem-fill``, ``--dem-fill-geoid``, ``--heights``) and a window
(``--roi``)."""

from __future__ import annotations

import argparse
import pathlib
from collections.abc import Sequence

from ._common import note, path_or_url


def add_image_options(parser: argparse.ArgumentParser) -> None:
    """``--model IMG=FILE`` and ``--image-origin IMG=COL,ROW`` (both repeatable)."""
    parser.add_argument(
        "--model",
        action="append",
        default=[],
        metavar="IMG=FILE",
        help="the sensor model file of image IMG (default: the RPC in the image or its "
        "sidecar), in its product's pixels; the adjusted_models.json of jaxgeo adjust gives "
        "IMG's adjusted model (bias and jitter); repeat per image",
    )
    parser.add_argument(
        "--image-origin",
        action="append",
        default=[],
        metavar="IMG=COL,ROW",
        help="model pixel of the first pixel of image IMG, for a crop whose model describes the "
        "full product (default: the crop's pixel-space geotransform, else 0,0)",
    )


def add_dem_options(parser: argparse.ArgumentParser, use: str) -> None:
    """``--dem``, ``--dem-height``, ``--geoid`` and :func:`add_dem_fill_options` (``use``: what
    the DEM is for, in the help)."""
    parser.add_argument("--dem", default=None, metavar="DEM", help=f"DEM raster (any CRS): {use}")
    add_height_options(parser)
    add_dem_fill_options(parser)


def add_dem_fill_options(parser: argparse.ArgumentParser) -> None:
    """``--dem-band``, ``--dem-fill``, ``--dem-fill-geoid`` (read by :func:`open_dem`)."""
    parser.add_argument("--dem-band", type=int, default=None, metavar="N",
                        help="band of heights of --dem (default: its only band, or a jaxgeo "
                        "DSM's band described 'height')")  # fmt: skip
    parser.add_argument("--dem-fill", default=None, metavar="DEM2",
                        help="a second DEM (any CRS) whose heights fill the holes of --dem and "
                        "reach beyond its edges, e.g. SRTM under a jaxgeo DSM")  # fmt: skip
    parser.add_argument("--dem-fill-geoid", default=None, metavar="GEOID",
                        help="the values of --dem-fill are orthometric above GEOID (egm96, "
                        "egm2008 or a geoid file; default: its vertical CRS if it declares one, "
                        "else ellipsoidal); both DEMs are made ellipsoidal before one fills the "
                        "other (--dem-height/--geoid describe --dem only)")  # fmt: skip


def add_height_options(
    parser: argparse.ArgumentParser,
    dem: str = "the DEM",
    default: str = "the file's vertical CRS if it declares EGM96/EGM2008, else ellipsoidal",
) -> None:
    """``--dem-height`` and ``--geoid``: the height reference of ``dem`` (a phrase for the help:
    ``"REF"`` where the DEM is a positional argument); ``default``: what is assumed without
    them. The values go to :func:`jaxgeo.io.read_dem` (``height=``, ``geoid=``)."""
    parser.add_argument(
        "--dem-height",
        choices=("ellipsoidal", "orthometric"),
        default=None,
        help=f"height reference of the values of {dem} (default: {default})",
    )
    parser.add_argument(
        "--geoid",
        default=None,
        help=f"egm96 (shipped), egm2008 (PROJ's grid) or a geoid grid file, for orthometric "
        f"heights of {dem} (implies --dem-height orthometric)",
    )


def check_height_options(args: argparse.Namespace) -> None:
    """``--geoid`` not with ``--dem-height ellipsoidal`` (a geoid converts orthometric
    heights)."""
    from . import CommandError

    if args.geoid is not None and args.dem_height == "ellipsoidal":
        raise CommandError(f"--geoid {args.geoid}: a geoid converts orthometric heights; not with "
                           "--dem-height ellipsoidal")  # fmt: skip


def add_heights(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--heights",
        type=float,
        nargs=2,
        default=None,
        metavar=("HMIN", "HMAX"),
        help="height range of the terrain, ellipsoidal m (default: from --dem, else from a "
        "first coarse matching)",
    )


def check_dem_options(args: argparse.Namespace) -> None:
    """``--heights`` finite and ordered; ``--geoid`` / ``--dem-height`` only with ``--dem``."""
    import math

    from . import CommandError

    if getattr(args, "heights", None) is not None:
        lo, hi = args.heights
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise CommandError(f"--heights {lo:g} {hi:g}: need finite HMIN < HMAX (metres)")
    if args.geoid is not None and args.dem is None:
        raise CommandError("--geoid applies to a DEM: give --dem too")
    if args.dem_height is not None and args.dem is None:
        raise CommandError("--dem-height applies to a DEM: give --dem too")
    check_dem_fill_options(args)


def check_dem_fill_options(args: argparse.Namespace) -> None:
    """``--dem-band``, ``--dem-fill`` need ``--dem``; ``--dem-fill-geoid`` needs ``--dem-fill``."""
    from . import CommandError

    for option, value, needs in (("--dem-band", args.dem_band, args.dem), ("--dem-fill",
                                 args.dem_fill, args.dem), ("--dem-fill-geoid",
                                 args.dem_fill_geoid, args.dem_fill)):  # fmt: skip
        if value is not None and needs is None:
            raise CommandError(f"{option} needs {'--dem-fill' if 'geoid' in option else '--dem'}")


def dem_inputs(args: argparse.Namespace) -> list:
    """The DEM, fill DEM and geoid files among a command's inputs (a URL: a RemotePath)."""
    files = [path_or_url(args.dem)] if args.dem is not None else []
    if getattr(args, "dem_fill", None) is not None:
        files.append(path_or_url(args.dem_fill))
    for geoid in (args.geoid, getattr(args, "dem_fill_geoid", None)):
        if geoid is not None and pathlib.Path(geoid).exists():
            files.append(pathlib.Path(geoid))
    return files


def open_dem(args: argparse.Namespace):
    """The :class:`~jaxgeo.io.DEM` of ``--dem`` (``--dem-height``, ``--geoid``, ``--dem-band``)
    with its holes filled from ``--dem-fill`` (``--dem-fill-geoid``); ``None`` without one. Its
    height reference is printed on stderr unless ``--quiet``."""
    if args.dem is None:
        return None
    from ..io import read_dem

    check_dem_fill_options(args)
    fill = None
    if args.dem_fill is not None:
        try:
            fill = read_dem(args.dem_fill, geoid=args.dem_fill_geoid)
        except ValueError as err:  # the fill's reference is --dem-fill-geoid, not --geoid
            text = str(err).replace("height= and geoid=", "--dem-fill-geoid")
            raise ValueError(f"--dem-fill: {text}") from None
    dem = read_dem(args.dem, height=args.dem_height, geoid=args.geoid, band=args.dem_band,
                   fill=fill)  # fmt: skip
    note(dem.describe(), getattr(args, "quiet", False))
    return dem


def check_roi(roi, image) -> tuple[int, int, int, int]:
    """``--roi X Y W H`` inside the raster of ``image``, else a named error."""
    from . import CommandError

    x, y, w, h = roi
    width, height = image.size
    if x < 0 or y < 0 or w <= 0 or h <= 0 or x + w > width or y + h > height:
        raise CommandError(
            f"--roi {x} {y} {w} {h}: not inside {image.path} ({width} x {height} px; need "
            "X, Y >= 0, W, H > 0, X + W <= width, Y + H <= height)"
        )
    return (x, y, w, h)


def _by_image(specs: Sequence[str], images: Sequence[str], option: str) -> dict[str, str]:
    """``{image path: value}`` from ``IMG=VALUE`` specs; IMG is the path as given, its file name
    or its stem; a spec without ``IMG=`` is allowed when there is one image. An IMG that names
    no image is refused with the names accepted (:func:`accepted_image_names`)."""
    from . import CommandError

    aliases = {}
    for img in images:
        path = path_or_url(img)  # a URL: its last segment (query string dropped)
        for alias in (img, path.name, path.stem):
            aliases.setdefault(alias, img)
    out = {}
    for spec in specs:
        key, sep, value = spec.partition("=")
        if not sep and len(images) == 1:
            key, value = images[0], spec
        if not sep and len(images) != 1 or key not in aliases:
            expected = "FILE" if option == "--model" else "COL,ROW"
            raise CommandError(
                f"{option} {spec!r}: expected IMG={expected} with IMG one of the images, by its "
                f"path, file name or stem: {accepted_image_names(images)}"
            )
        img = aliases[key]
        if img in out:
            raise CommandError(f"{option}: image {img} given twice")
        out[img] = value
    return out


def accepted_image_names(images: Sequence[str]) -> str:
    """The names an ``IMG`` may take for each image (its path as given, file name, stem), for a
    message: ``"a/left.tif (left.tif, left); b/right.tif (right.tif, right)"``."""
    out = []
    for img in images:
        path = path_or_url(img)
        others = list(dict.fromkeys(a for a in (path.name, path.stem) if a != img))
        out.append(f"{img} ({', '.join(others)})" if others else img)
    return "; ".join(out)


def _origin(text: str, option_value: str):
    from . import CommandError

    try:
        col, row = (float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise CommandError(f"--image-origin {option_value!r}: expected IMG=COL,ROW") from None
    return col, row


def open_images(paths: Sequence[str], args: argparse.Namespace):
    """The :class:`~jaxgeo.io.SensorImage` of each raster in ``paths`` (``args.model`` and
    ``args.image_origin`` applied); file stems must differ (they name the images)."""
    from ..io import open_image
    from . import CommandError

    names = [path_or_url(p).stem for p in paths]
    if len(set(names)) != len(names):
        raise CommandError("image file names (stems) must differ: they name the images")
    models, origins = image_settings(args, list(paths))
    return [open_image(p, model=models.get(p), origin=origins.get(p)) for p in paths]


def image_settings(args: argparse.Namespace, images: Sequence[str]) -> tuple[dict, dict]:
    """``({image: model file}, {image: (col, row)})`` from ``--model`` and ``--image-origin``
    (IMG is an entry of ``images``, its file name or its stem)."""
    models = _by_image(getattr(args, "model", None) or [], images, "--model")
    specs = getattr(args, "image_origin", None) or []
    origins = {k: _origin(v, v) for k, v in _by_image(specs, images, "--image-origin").items()}
    return models, origins
