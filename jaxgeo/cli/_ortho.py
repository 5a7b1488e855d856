"""``jaxgeo ortho IMAGE --dem DEM -o OUT.tif``: orthorectify an image with its model and a DEM."""

from __future__ import annotations

import argparse
import pathlib


def register(sub) -> None:
    parser = sub.add_parser(
        "ortho",
        help="orthorectify an image with its RPCs (or any model file) and a DEM",
        description=(
            "Orthorectify IMAGE on DEM into a tiled, compressed COG. The model is the image's own "
            "RPC (GeoTIFF tags, .RPB/_RPC.TXT sidecar) unless --model names a model file. "
            "Default CRS: the local UTM zone; default resolution: the image's GSD."
        ),
    )
    parser.add_argument("image", metavar="IMAGE", help="the image (any raster GDAL reads)")
    parser.add_argument("--dem", required=True, help="DEM raster (any CRS)")
    parser.add_argument("--dem-height", choices=("ellipsoidal", "orthometric"), default=None,
                        help="height reference of the DEM values (default: the file's vertical "
                        "CRS if it declares EGM96/EGM2008, else ellipsoidal)")  # fmt: skip
    parser.add_argument("--geoid", default=None,
                        help="egm96, egm2008 (PROJ grids) or a geoid grid file, for orthometric "
                        "DEMs (implies --dem-height orthometric)")  # fmt: skip
    parser.add_argument("--model", default=None, help="model file (any RPC format jaxgeo reads)")
    parser.add_argument("--image-origin", nargs=2, type=float, default=(0.0, 0.0),
                        metavar=("COL", "ROW"),
                        help="model pixel of the image's first pixel (for crops)")  # fmt: skip
    parser.add_argument("--crs", default=None, help="output CRS, e.g. EPSG:32631 (default UTM)")
    parser.add_argument("--res", type=float, default=None, help="output pixel size (CRS units)")
    parser.add_argument("--resampling", choices=("nearest", "bilinear", "cubic"),
                        default="bilinear", help="image resampling (default bilinear)")  # fmt: skip
    parser.add_argument(
        "--bounds",
        nargs=4,
        type=float,
        default=None,
        metavar=("W", "S", "E", "N"),
        help="output bounds in the output CRS",
    )
    parser.add_argument(
        "--occlusion",
        choices=("off", "nodata", "band"),
        default="off",
        help="terrain hidden from the sensor: nodata, or an extra mask band",
    )
    parser.add_argument("--tile", type=int, default=1024, help="tile size (px)")
    parser.add_argument("-o", "--out", required=True, help="output GeoTIFF (COG)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from jaxgeo.io import read_dem, read_rpc
    from jaxgeo.ortho import orthorectify

    from . import CommandError

    out = pathlib.Path(args.out)
    if out.exists() and not args.overwrite:
        raise CommandError(f"{out}: exists; pass --overwrite to replace it")
    source = args.model or args.image
    try:
        model = read_rpc(source)
    except (ValueError, KeyError) as err:
        raise CommandError(
            f"{source}: no sensor model found ({err}); give one with --model"
        ) from None
    dem = read_dem(args.dem, height=args.dem_height, geoid=args.geoid)
    report = orthorectify(
        args.image, model, dem, out, crs=args.crs, res_m=args.res, bounds=args.bounds,
        resampling=args.resampling, occlusion=args.occlusion, image_origin=args.image_origin,
        tile_px=args.tile, overwrite=args.overwrite, progress=not args.no_progress,
    )  # fmt: skip
    print(f"wrote {report.path}: {report.width} x {report.height} px, {report.res_m:.3f} m, "
          f"{report.crs}; {100 * report.valid_fraction:.1f}% with data; grid error left "
          f"{report.grid_error_px:.2g} px ({100 * report.refined_fraction:.1f}% of blocks "
          f"projected in full); {report.seconds:.1f} s")  # fmt: skip
    if report.occluded_fraction is not None:
        print(f"occluded: {100 * report.occluded_fraction:.2f}% of the output")
    return 0
