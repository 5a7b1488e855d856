"""File input/output: vendor RPC files, GCP/tie-point tables, metadata, adjusted-model writers.

``observations`` holds the data types the layers above share (:class:`GroundPoints`,
:class:`Observations`); ``rpc_keys`` the one table of vendor RPC keys every RPC reader and writer
uses; ``atomic`` the one writer every output goes through (atomic, never overwrites unless asked).

Image coordinates in every file jaxgeo writes follow its convention (integer values at pixel
centres, ``(0, 0)`` the centre of the first pixel); readers convert vendor conventions on input.
"""

# --- other io modules (tables, metadata, ...) re-export below this line ---
from ._dem import DEM as DEM
from ._dem import read_dem as read_dem
from ._image import ImageError as ImageError
from ._image import SensorImage as SensorImage
from ._image import open_image as open_image
from ._metadata import MetadataError as MetadataError
from ._metadata import read_metadata as read_metadata
from ._metadata import write_metadata_json as write_metadata_json
from ._observations import GroundPoints as GroundPoints
from ._observations import Observations as Observations
from ._rpc_accuracy import RPCAccuracy as RPCAccuracy
from ._rpc_common import RPCFormatError as RPCFormatError
from ._rpc_formats import read_rpc as read_rpc
from ._rpc_formats import read_rpc_accuracy as read_rpc_accuracy
from ._rpc_gdal import from_rasterio_rpc as from_rasterio_rpc
from ._rpc_gdal import to_rasterio_rpc as to_rasterio_rpc
from ._rpc_gdal import write_geotiff_rpc as write_geotiff_rpc
from ._rpc_geom_dimap import write_dimap_rpc as write_dimap_rpc
from ._rpc_geom_dimap import write_ossim_geom as write_ossim_geom
from ._rpc_text import write_rpb as write_rpb
from ._rpc_text import write_rpc_text as write_rpc_text
from ._tables import TableError as TableError
from ._tables import read_ground as read_ground
from ._tables import read_observations as read_observations
from ._tables import write_ground as write_ground
from ._tables import write_observations as write_observations
