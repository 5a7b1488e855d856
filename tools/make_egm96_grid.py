"""Convert NGA's EGM96 15' geoid grid ``WW15MGH.DAC`` into ``jaxgeo/io/data/egm96_15.tif``.

    python tools/make_egm96_grid.py WW15MGH.DAC jaxgeo/io/data/egm96_15.tif

``WW15MGH.DAC`` (NGA, public domain, US government work; 2 076 480 bytes) holds the EGM96
undulations ``N`` on a 15-arcminute grid: 721 rows x 1440 columns of big-endian int16 in
centimetres, row 0 at latitude 90 N, column 0 at longitude 0 E, 0.25 degree steps (nodes, not
cells). The GeoTIFF keeps the values (int16 cm, band scale 0.01: metres when read with it) and
rolls the columns so that they run from 180 W; a node is the centre of its cell (GDAL's
pixel-is-area convention, as PROJ's ``us_nga_egm96_15.tif`` is written), EPSG:4326,
DEFLATE with a horizontal predictor (about 2 MB).
"""

from __future__ import annotations

import hashlib
import pathlib
import sys

import numpy as np

ROWS, COLS, STEP_DEG = 721, 1440, 0.25


def main(src: str, dst: str) -> None:
    import rasterio
    from affine import Affine

    raw = pathlib.Path(src).read_bytes()
    if len(raw) != ROWS * COLS * 2:
        raise SystemExit(f"{src}: {len(raw)} bytes, expected {ROWS * COLS * 2} (721 x 1440 int16)")
    cm = np.frombuffer(raw, dtype=">i2").reshape(ROWS, COLS)
    cm = np.roll(cm, COLS // 2, axis=1).astype("int16")  # column 0 at 180 W
    profile = dict(
        driver="GTiff", width=COLS, height=ROWS, count=1, dtype="int16", crs="EPSG:4326",
        transform=Affine(STEP_DEG, 0.0, -180.0 - STEP_DEG / 2, 0.0, -STEP_DEG,
                         90.0 + STEP_DEG / 2),
        compress="deflate", predictor=2, zlevel=9, tiled=False,
    )  # fmt: skip
    with rasterio.open(dst, "w", **profile) as out:
        out.write(cm, 1)
        out.scales = (0.01,)
        out.offsets = (0.0,)
        out.set_band_unit(1, "m")
        out.set_band_description(1, "EGM96 geoid undulation N (m above the WGS84 ellipsoid)")
        out.update_tags(
            source="NGA EGM96 15-arcminute geoid undulations, WW15MGH.DAC (public domain)",
            source_sha256=hashlib.sha256(raw).hexdigest(),
            converted_by="tools/make_egm96_grid.py",
        )


if __name__ == "__main__":
    main(*sys.argv[1:3])
