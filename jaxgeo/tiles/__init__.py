"""Whole scenes tile by tile: a plan of tiles, a runner over dask.distributed, a COG mosaic.

    plan = plan_tiles("ortho", width, height, tile_px=1024, job={...})
    product = make_product(plan, work, "product.tif", spec, TileSettings(workers=None))
    product.total.valid_px                               # work(tile, path) -> stats | None

(:func:`make_product`: :func:`run_tiles` in a work folder, :func:`mosaic_cog`, the folder
removed; each tile's statistics a :class:`TileStats`).

Generic over what a tile produces: the orthoimage (:mod:`jaxgeo.ortho`) runs on it with its own
per-tile function (:class:`jaxgeo.ortho.OrthoJob`); other raster products can do the same. By
default the tiles of a large product run on an embedded dask LocalCluster of spawned worker
processes, one per core, and a small product's in this process; ``scheduler=`` names an
existing dask cluster (:mod:`._runner` says how to start one).
"""

from ._grid import OutputGrid as OutputGrid
from ._mosaic import RasterSpec as RasterSpec
from ._plan import PlanError as PlanError
from ._plan import Tile as Tile
from ._plan import TilePlan as TilePlan
from ._plan import plan_tiles as plan_tiles
from ._plan import read_plan as read_plan
from ._plan import write_plan as write_plan
from ._product import EmptyProduct as EmptyProduct
from ._product import ProductRun as ProductRun
from ._product import TileStats as TileStats
from ._product import make_product as make_product
from ._runner import TileError as TileError
from ._runner import run_tiles as run_tiles
from ._settings import TileSettings as TileSettings
