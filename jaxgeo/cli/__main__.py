"""``python -m jaxgeo.cli``."""

from . import entry

entry()
