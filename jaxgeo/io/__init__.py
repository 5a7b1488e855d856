"""File input/output: vendor RPC files, GCP/tie-point tables, metadata, adjusted-model writers.

``observations`` holds the data types the layers above share (:class:`GroundPoints`,
:class:`Observations`); ``rpc_keys`` the one table of vendor RPC keys every RPC reader and writer
uses; ``atomic`` the one writer every output goes through (atomic, never overwrites unless asked).

Image coordinates in every file jaxgeo writes follow its convention (integer values at pixel
centres, ``(0, 0)`` the centre of the first pixel); readers convert vendor conventions on input.
"""

# --- other io modules (tables, metadata, ...) re-export below this line ---
from .dem import DEM as DEM
from .dem import read_dem as read_dem
from .metadata import MetadataError as MetadataError
from .metadata import SceneMetadata as SceneMetadata
from .metadata import read_metadata as read_metadata
from .metadata import write_metadata_json as write_metadata_json
from .observations import GroundPoints as GroundPoints
from .observations import Observations as Observations
from .rpc_common import RPCFormatError as RPCFormatError
from .rpc_formats import detect_rpc_format as detect_rpc_format
from .rpc_formats import read_rpc as read_rpc
from .rpc_gdal import from_rasterio_rpc as from_rasterio_rpc
from .rpc_gdal import to_rasterio_rpc as to_rasterio_rpc
from .rpc_gdal import write_geotiff_rpc as write_geotiff_rpc
from .rpc_keys import RPC_KEYS as RPC_KEYS
from .rpc_text import write_rpb as write_rpb
from .rpc_text import write_rpc_text as write_rpc_text
from .tables import TableError as TableError
from .tables import read_ground as read_ground
from .tables import read_observations as read_observations
from .tables import write_ground as write_ground
from .tables import write_observations as write_observations
