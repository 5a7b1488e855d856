"""Physically based synthetic scenes: Cartosat-1 stereo pairs, Carto-2S strips, and rendered
Pleiades-like stereo scenes of any size (:func:`stereo_scene`: images with vendor RPCs in their
GeoTIFF tags, a truth DSM and the true models, streamed to disk).

Each simulation takes its options as one frozen settings object (:class:`Cartosat1Settings`,
:class:`Carto2SStripSettings`, :class:`StereoSceneSettings`: a bad value raises
:class:`SimulationError` naming the field), is deterministic in its ``seed`` and returns a
dataclass holding the truth (rigorous :class:`~jaxgeo.models.EphemerisModel` s), the "vendor"
RPCs fitted to a perturbed copy of it, ground points and image measurements; ``.save(dir)``
writes them with jaxgeo's own writers (RPC text, GROUND/OBS CSV tables, a ``truth.json``), ready
for ``jaxgeo adjust``. :func:`write_cartosat1_stereo`, :func:`write_carto2s_strip` and
:func:`stereo_scene` simulate and write in one call (what ``jaxgeo simulate`` runs).
"""

from ._carto2s import Carto2SStripSettings as Carto2SStripSettings
from ._carto2s import StripScene as StripScene
from ._carto2s import carto2s_strip as carto2s_strip
from ._carto2s import write_carto2s_strip as write_carto2s_strip
from ._cartosat1 import Cartosat1Settings as Cartosat1Settings
from ._cartosat1 import StereoScene as StereoScene
from ._cartosat1 import cartosat1_stereo as cartosat1_stereo
from ._cartosat1 import write_cartosat1_stereo as write_cartosat1_stereo
from ._demo import demo_dir as demo_dir
from ._demo import write_demo as write_demo
from ._orbit import CircularOrbit as CircularOrbit
from ._orbit import EphemerisSettings as EphemerisSettings
from ._orbit import ephemeris_from_orbit as ephemeris_from_orbit
from ._render import RenderSettings as RenderSettings
from ._scene import SimulationError as SimulationError
from ._stereo_scene import StereoSceneSettings as StereoSceneSettings
from ._stereo_scene import StereoSceneTruth as StereoSceneTruth
from ._stereo_scene import read_stereo_scene as read_stereo_scene
from ._stereo_scene import stereo_scene as stereo_scene
from ._stereo_scene import stereo_scene_truth as stereo_scene_truth
from ._stereo_scene import write_stereo_scene as write_stereo_scene
from ._stereo_scene_models import JitteredModel as JitteredModel
from ._terrain import Terrain as Terrain
from ._terrain import TerrainChange as TerrainChange
