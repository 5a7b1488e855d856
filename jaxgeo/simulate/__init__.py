"""Physically based synthetic scenes: Cartosat-1 stereo pairs and Carto-2S strips.

Each simulation is deterministic in its ``seed`` and returns a dataclass holding the truth
(rigorous :class:`~jaxgeo.models.EphemerisModel` s), the "vendor" RPCs fitted to a perturbed copy
of it, ground points and image measurements; ``.save(dir)`` writes them with jaxgeo's own writers
(RPC text, GROUND/OBS CSV tables, a ``truth.json``), ready for ``jaxgeo adjust``.
"""

from .carto2s import StripScene as StripScene
from .carto2s import carto2s_strip as carto2s_strip
from .cartosat1 import StereoScene as StereoScene
from .cartosat1 import cartosat1_stereo as cartosat1_stereo
from .demo import DEMO_SEED as DEMO_SEED
from .demo import demo_dir as demo_dir
from .demo import demo_scene as demo_scene
from .demo import write_demo as write_demo
from .orbit import CircularOrbit as CircularOrbit
from .orbit import ephemeris_from_orbit as ephemeris_from_orbit
from .scene import VendorErrors as VendorErrors
from .terrain import Terrain as Terrain
