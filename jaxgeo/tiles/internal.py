"""Stages of :mod:`jaxgeo.tiles` that other jaxgeo packages use: not the user API (names here
may change without notice); a user imports from ``jaxgeo.tiles``."""

from ._mosaic import COMPRESSIONS as COMPRESSIONS
from ._mosaic import overview_factors as overview_factors
from ._mosaic import write_tile as write_tile
from ._product import DEFAULT_TILES as DEFAULT_TILES
from ._runner import NoData as NoData
from ._runner import WorkerPool as WorkerPool
from ._runner import cores as cores
from ._settings import MAX_RETRIES as MAX_RETRIES
from ._settings import max_local_workers as max_local_workers
