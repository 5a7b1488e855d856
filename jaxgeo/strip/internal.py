"""Stages of :mod:`jaxgeo.strip` that other jaxgeo packages use: not the user API (names here
may change without notice); a user imports from ``jaxgeo.strip``."""

from ._config import DEGREES as DEGREES
