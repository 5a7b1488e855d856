"""Stages of :mod:`jaxgeo.io` that other jaxgeo packages use: not the user API (names here
may change without notice); a user imports from ``jaxgeo.io``."""

from ._adjusted import JITTER_STATICS as JITTER_STATICS
from ._atomic import atomic_output as atomic_output
from ._atomic import atomic_write_text as atomic_write_text
from ._atomic import claim_output as claim_output
from ._atomic import refuse_existing as refuse_existing
from ._atomic import write_bytes as write_bytes
from ._atomic import write_csv as write_csv
from ._dem_grid import dem_coverage as dem_coverage
from ._image import pixel_frame as pixel_frame
from ._image import reframed as reframed
from ._plausible import dem_against_model as dem_against_model
from ._plausible import dem_against_ties as dem_against_ties
from ._raster import open_raster as open_raster
from ._raster import raster_writer as raster_writer
from ._remote import as_path as as_path
from ._remote import file_id as file_id
from ._remote import is_remote as is_remote
from ._rpc_common import vendor_values as vendor_values
from ._rpc_formats import detect_rpc_format as detect_rpc_format
from ._rpc_place import image_stem as image_stem
from ._rpc_place import plan_rpc_outputs as plan_rpc_outputs
from ._rpc_place import sidecar_name as sidecar_name
from ._rpc_place import write_rpc_outputs as write_rpc_outputs
from ._rpc_text import format_rpc_txt as format_rpc_txt
from ._tables import table_lines as table_lines
