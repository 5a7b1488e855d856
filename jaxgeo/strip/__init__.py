"""Two-level full-strip adjustment (003_a7d3ea260371d8c5.txt sections 6-9).

``adjust_strip(read_strip("strip.json"), StripConfig())``: ties formed from the sub-scenes'
line offsets, one bundle adjustment of all sub-scenes (level 1), the universal correction of
eq. 12-13 from the GCPs (level 2), reports per sub-scene; ``monte_carlo`` runs a batch in one
vmapped call. Modules, in the order the data passes them:

- ``config``: ``TieConfig``, ``Level1Config``, ``Level2Config``, ``RefitConfig``,
  ``StripConfig`` (frozen, checked settings);
- ``errors``: ``ConfigError`` (names the settings at fault), ``StripFormatError``, warnings;
- ``delivery``: the strip as delivered (``SubScene``, ``Strip``, ``read_strip``);
- ``distribution``: the GCP distribution rule of section 9;
- ``ties``: tie points formed from the line offsets;
- ``level1``: level-1 observations and ground points (ties, tie height priors, GCPs);
- ``level2``: level-2 data (GCP, check and tie rows);
- ``universal``: the universal correction of eq. 12-13;
- ``solve``: both levels as one pure function of arrays (jit, vmap);
- ``snooping``: gross errors at both levels (robust loss, w-test, removal) and wrong line
  offsets (the seams of the vendor RPCs);
- ``report``: per sub-scene and per pair figures;
- ``result``: ``StripResult`` and the refitted RPCs;
- ``adjustment``: ``adjust_strip`` (tables in, result out), ``adjust_individually``;
- ``batch``: Monte-Carlo batches and timing of the compiled call.
"""

from .adjustment import N_BIAS_GCPS as N_BIAS_GCPS
from .adjustment import adjust_individually as adjust_individually
from .adjustment import adjust_strip as adjust_strip
from .adjustment import evaluate_models as evaluate_models
from .batch import monte_carlo as monte_carlo
from .batch import time_two_level as time_two_level
from .config import DEGREES as DEGREES
from .config import Level1Config as Level1Config
from .config import Level2Config as Level2Config
from .config import RefitConfig as RefitConfig
from .config import StripConfig as StripConfig
from .config import TieConfig as TieConfig
from .delivery import Strip as Strip
from .delivery import StripFiles as StripFiles
from .delivery import SubScene as SubScene
from .delivery import read_strip as read_strip
from .distribution import GCPDistributionWarning as GCPDistributionWarning
from .distribution import check_gcp_distribution as check_gcp_distribution
from .errors import ConfigError as ConfigError
from .errors import LineOffsetWarning as LineOffsetWarning
from .errors import MeasuredTieWarning as MeasuredTieWarning
from .errors import Setting as Setting
from .errors import StripFormatError as StripFormatError
from .errors import UniversalCorrectionWarning as UniversalCorrectionWarning
from .level2 import Level2Data as Level2Data
from .report import GrossErrors as GrossErrors
from .report import StripReport as StripReport
from .result import StripResult as StripResult
from .solve import TwoLevelSolution as TwoLevelSolution
from .solve import two_level as two_level
from .ties import strip_ties as strip_ties
from .universal import UniversalCorrection as UniversalCorrection
from .universal import UniversallyCorrected as UniversallyCorrected
from .universal import fit_universal_correction as fit_universal_correction
