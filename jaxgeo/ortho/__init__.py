"""Orthorectification with any sensor model and a DEM (tiled on all cores, COG output, occlusion).

from jaxgeo.ortho import orthorectify
report = orthorectify("scene.tif", None, read_dem("dem.tif", geoid="egm96"), "ortho.tif")

The tiles of a large product run on dask workers (:mod:`jaxgeo.tiles`); :func:`plan_ortho` checks
the options and plans the tiles without computing any.
"""

from ._grid import OutputGrid as OutputGrid
from ._job import DEMSource as DEMSource
from ._job import OrthoJob as OrthoJob
from ._pipeline import OrthoReport as OrthoReport
from ._pipeline import orthorectify as orthorectify
from ._plan import OrthoSetup as OrthoSetup
from ._plan import plan_ortho as plan_ortho
from ._validate import MAX_PIXELS as MAX_PIXELS
from ._validate import OrthoError as OrthoError
