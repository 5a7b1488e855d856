"""The embedded demo scene: a Cartosat-1 stereo pair over a Hobart-like site, fixed seed.

``jaxgeo/data/cartosat1_demo/`` holds what :func:`write_demo` writes (``fore.txt``, ``aft.txt``,
``ground.csv``, ``observations.csv``, ``truth.json``): 69 GPS points in the top-left quarter
(9 GCPs, 60 check points), measured with 0.3 px noise, vendor RPCs biased by tens of pixels.
The test suite regenerates it and compares the bytes.
"""

from __future__ import annotations

import importlib.resources
import os
import pathlib

from ._cartosat1 import Cartosat1Settings, StereoScene, cartosat1_stereo

DEMO_SEED = 2006
DEMO_NAME = "cartosat1_demo"


def demo_dir() -> pathlib.Path:
    """Folder of the packaged demo scene (read-only; copy it before writing beside it)."""
    return pathlib.Path(str(importlib.resources.files("jaxgeo") / "data" / DEMO_NAME))


def demo_scene() -> StereoScene:
    """The demo scene, simulated afresh (identical to the packaged files)."""
    return cartosat1_stereo(DEMO_SEED, Cartosat1Settings(site="hobart"))


def write_demo(directory: str | os.PathLike, overwrite: bool = False) -> list[pathlib.Path]:
    """(Re)generate the demo files into ``directory``."""
    return demo_scene().save(directory, overwrite=overwrite)
