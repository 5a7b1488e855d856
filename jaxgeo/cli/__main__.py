"""``python -m jaxgeo.cli``."""

import sys

from . import main

sys.exit(main())
