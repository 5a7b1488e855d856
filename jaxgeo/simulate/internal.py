"""Stages of :mod:`jaxgeo.simulate` that other jaxgeo packages use: not the user API (names here
may change without notice); a user imports from ``jaxgeo.simulate``."""

from ._stereo_scene import stereo_scene_files as stereo_scene_files
