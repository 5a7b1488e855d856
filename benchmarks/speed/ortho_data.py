"""Whole-scene orthorectification inputs: an N x N px crop of the Ventoux Pleiades product with its
RPC in the GeoTIFF tags, and an ellipsoidal DEM (SRTM 90 m + EGM96) around it.

    python -m benchmarks.speed.ortho_data --size 12000 --out /tmp/ortho_12000

The crop is centred on the full product (40 000 x 42 000 px, the ``phr_ventoux__left_image.geom``
RPC); its pixels are a uint16 texture (a few sinusoids and noise, written tile by tile so memory
does not grow with N); its RPC is the product's moved to the crop (offsets minus the crop
origin), so GDAL and jaxgeo read the same model from the file. Written once, reused (`scene.tif`,
`dem.tif` in the folder).
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys

import numpy as np

from benchmarks.data import REAL_DATA

GEOM = REAL_DATA / "phr_ventoux__left_image.geom"
SRTM = REAL_DATA / "ventoux" / "dem" / "N44E005_srtm90.tif"
EGM96 = REAL_DATA / "ventoux" / "dem" / "egm96_15_crop_lon3-8_lat42-47.gtx"


def crop_rpc(size: int):
    """The product RPC moved to the ``size`` px crop centred on the product, and the crop origin."""
    import equinox as eqx
    import jax.numpy as jnp

    import jaxgeo

    rpc = jaxgeo.read_rpc(GEOM)
    centre = np.asarray(rpc.image_offset)
    origin = np.floor(centre - size / 2)
    moved = eqx.tree_at(lambda m: m.image_offset, rpc, rpc.image_offset - jnp.asarray(origin))
    return moved, (float(origin[0]), float(origin[1]))


def write_scene(path: pathlib.Path, size: int, rpc, block: int = 1024, seed: int = 0) -> None:
    """``size`` x ``size`` uint16 texture, tiled 256 px, uncompressed, with ``rpc`` as tags."""
    import rasterio
    from rasterio.windows import Window

    from jaxgeo.io import write_geotiff_rpc

    rng = np.random.default_rng(seed)
    profile = dict(driver="GTiff", width=size, height=size, count=1, dtype="uint16", tiled=True,
                   blockxsize=256, blockysize=256, BIGTIFF="IF_SAFER")  # fmt: skip
    tmp = path.with_suffix(".tmp.tif")
    with rasterio.open(tmp, "w", **profile) as dst:
        for r0 in range(0, size, block):
            for c0 in range(0, size, block):
                rows, cols = min(block, size - r0), min(block, size - c0)
                rr, cc = np.mgrid[r0 : r0 + rows, c0 : c0 + cols].astype(float)
                v = (
                    2000
                    + 600 * np.sin(cc / 7.3) * np.cos(rr / 11.1)
                    + 300 * np.sin((cc + rr) / 53.0)
                )
                v += rng.normal(0, 80, v.shape)
                dst.write(np.clip(v, 0, 65535).astype("uint16"), 1,
                          window=Window(c0, r0, cols, rows))  # fmt: skip
    write_geotiff_rpc(rpc, tmp, update=True)
    tmp.replace(path)


def write_ellipsoidal_dem(path: pathlib.Path, box, margin_deg: float = 0.01) -> None:
    """SRTM + EGM96 undulation (ellipsoidal heights, float32, EPSG:4326) over ``box``."""
    import rasterio
    from affine import Affine

    from jaxgeo.io._geoid import read_geoid

    w, s, e, n = box
    geoid = read_geoid(EGM96)
    with rasterio.open(SRTM) as src:
        t = src.transform
        c0 = int(math.floor((w - margin_deg - t.c) / t.a))
        r0 = int(math.floor((t.f - (n + margin_deg)) / -t.e))
        c1 = int(math.ceil((e + margin_deg - t.c) / t.a))
        r1 = int(math.ceil((t.f - (s - margin_deg)) / -t.e))
        win = rasterio.windows.Window(c0, r0, c1 - c0, r1 - r0)
        z = src.read(1, window=win, masked=True).astype(float).filled(np.nan)
        wt = src.window_transform(win)
    rr, cc = np.mgrid[0 : z.shape[0], 0 : z.shape[1]]
    z = z + geoid(wt.c + (cc + 0.5) * wt.a, wt.f + (rr + 0.5) * wt.e)
    profile = dict(driver="GTiff", width=z.shape[1], height=z.shape[0], count=1,
                   dtype="float32", crs="EPSG:4326", nodata=np.nan,
                   transform=Affine(wt.a, 0, wt.c, 0, wt.e, wt.f))  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(z.astype("float32"), 1)


def make_scene(folder: str | pathlib.Path, size: int) -> tuple[pathlib.Path, pathlib.Path]:
    """``(scene.tif, dem.tif)`` in ``folder``, written unless already there."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    scene, dem = folder / "scene.tif", folder / "dem.tif"
    if scene.exists() and dem.exists():
        return scene, dem
    rpc, _ = crop_rpc(size)
    if not scene.exists():
        write_scene(scene, size, rpc)
    # the crop's footprint at the terrain's height range, on the ground
    border = np.array([[0, 0], [size, 0], [0, size], [size, size]], dtype=float) - 0.5
    pts = np.concatenate([np.asarray(rpc.localize(border, h)) for h in (0.0, 2000.0)])
    box = (pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max(), pts[:, 1].max())
    write_ellipsoidal_dem(dem, box)
    return scene, dem


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=2000, help="image size (px, square)")
    p.add_argument("--out", required=True, help="folder for scene.tif and dem.tif")
    a = p.parse_args(argv)
    scene, dem = make_scene(a.out, a.size)
    print(scene, dem)
    return 0


if __name__ == "__main__":
    sys.exit(main())
