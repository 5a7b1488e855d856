"""Orthorectification with any sensor model and a DEM (tiled on all cores, COG output, occlusion).

from jaxgeo.ortho import OrthoSettings, orthorectify
report = orthorectify("scene.tif", read_dem("dem.tif", geoid="egm96"), "ortho.tif",
                      OrthoSettings(crs="EPSG:32631", res_m=0.5))

:class:`OrthoSettings` says what the product is (grid, resampling, occlusion, tiles, limits);
the tiles of a large product run on dask workers as :class:`jaxgeo.tiles.TileSettings` says;
:func:`plan_ortho` takes the same arguments, checks them and plans the tiles without computing
any.

The products of one job share a grid: by default the resolution is the image's GSD rounded to a
common value (:func:`common_resolution`) and the grid's edges are multiples of it
(target-aligned pixels, ``tap``); ``OrthoSettings(like="other.tif")`` takes another raster's
grid exactly.
"""

from ._grid import OutputGrid as OutputGrid
from ._grid import common_resolution as common_resolution
from ._job import DEMSource as DEMSource
from ._job import OrthoJob as OrthoJob
from ._pipeline import OrthoReport as OrthoReport
from ._pipeline import orthorectify as orthorectify
from ._plan import OrthoSetup as OrthoSetup
from ._plan import plan_ortho as plan_ortho
from ._settings import OCCLUSIONS as OCCLUSIONS
from ._settings import OrthoSettings as OrthoSettings
from ._validate import MAX_PIXELS as MAX_PIXELS
from ._validate import OrthoError as OrthoError
