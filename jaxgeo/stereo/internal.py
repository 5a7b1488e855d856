"""Stages of :mod:`jaxgeo.stereo` that other jaxgeo packages use: not the user API (names here
may change without notice); a user imports from ``jaxgeo.stereo``."""

from ._uncertainty import orientation_covariances as orientation_covariances
