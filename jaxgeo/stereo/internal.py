"""Stages of :mod:`jaxgeo.stereo` that other jaxgeo packages use: not the user API (names here
may change without notice); a user imports from ``jaxgeo.stereo``."""

from ._uncertainty import adjusted_orientation as adjusted_orientation
