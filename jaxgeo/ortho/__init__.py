"""Orthorectification with any sensor model and a DEM (tiled, COG output, occlusion mask).

from jaxgeo.ortho import orthorectify
report = orthorectify("scene.tif", model, read_dem("dem.tif", geoid="egm96"), "ortho.tif")
"""

from ._grid import OutputGrid as OutputGrid
from ._pipeline import OrthoReport as OrthoReport
from ._pipeline import orthorectify as orthorectify
