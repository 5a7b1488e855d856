"""Stages of :mod:`jaxgeo.lsq` that other jaxgeo packages use: not the user API (names here
may change without notice); a user imports from ``jaxgeo.lsq``."""

from ._config import BLUNDER_K as BLUNDER_K
from ._config import DEFAULT_SOLVER as DEFAULT_SOLVER
from ._covariance import INFLATION_MAX as INFLATION_MAX
from ._covariance import undetermined_unknowns as undetermined_unknowns
from ._factor import inv3_spd as inv3_spd
from ._loss import irls_weights as irls_weights
from ._results import describe as describe
from ._schur import reduced_system as reduced_system
