"""Two-level full-strip adjustment (003_a7d3ea260371d8c5.txt sections 6-9).

``adjust_strip(read_strip("strip.json"), StripConfig())``: ties formed from the sub-scenes'
line offsets, one bundle adjustment of all sub-scenes (level 1), the universal correction of
eq. 12-13 from the GCPs (level 2), reports per sub-scene; ``monte_carlo`` runs a batch in one
vmapped call. Its private modules, in the order the data passes them (their names are
public here):

- ``_config``: ``TieConfig``, ``Level1Config``, ``Level2Config``, ``RefitConfig``,
  ``StripConfig`` (frozen, checked settings);
- ``_errors``: ``ConfigError`` (names the settings at fault), ``StripFormatError``, warnings;
- ``_delivery``: the strip as delivered (``SubScene``, ``Strip``, ``read_strip``);
- ``_distribution``: the GCP distribution rule of section 9;
- ``_ties``: tie points formed from the line offsets;
- ``_level1``: level-1 observations and ground points (ties, tie height priors, GCPs);
- ``_level2``: level-2 data (GCP, check and tie rows);
- ``_universal``: the universal correction of eq. 12-13;
- ``_solve``: both levels as one pure function of arrays (jit, vmap);
- ``_snooping``: gross errors at both levels (robust loss, w-test, removal) and wrong line
  offsets (the seams of the vendor RPCs);
- ``_report``: per sub-scene and per pair figures;
- ``_result``: ``StripResult`` and the refitted RPCs;
- ``_adjustment``: ``adjust_strip`` (tables in, result out), ``adjust_individually``;
- ``_files``: ``adjust_strip_files`` (files in, a ``StripFileAdjustment`` out, written with its
  ``write``; what ``jaxgeo strip`` runs), ``StripOutputs``;
- ``_batch``: Monte-Carlo batches and timing of the compiled call.
"""

from ._adjustment import adjust_individually as adjust_individually
from ._adjustment import adjust_strip as adjust_strip
from ._adjustment import evaluate_models as evaluate_models
from ._batch import monte_carlo as monte_carlo
from ._config import Level1Config as Level1Config
from ._config import Level2Config as Level2Config
from ._config import RefitConfig as RefitConfig
from ._config import StripConfig as StripConfig
from ._config import TieConfig as TieConfig
from ._delivery import Strip as Strip
from ._delivery import read_strip as read_strip
from ._distribution import GCPDistributionWarning as GCPDistributionWarning
from ._distribution import check_gcp_distribution as check_gcp_distribution
from ._errors import ConfigError as ConfigError
from ._errors import LineOffsetWarning as LineOffsetWarning
from ._errors import MeasuredTieWarning as MeasuredTieWarning
from ._errors import StripFormatError as StripFormatError
from ._errors import UniversalCorrectionWarning as UniversalCorrectionWarning
from ._files import StripFileAdjustment as StripFileAdjustment
from ._files import StripOutputs as StripOutputs
from ._files import adjust_strip_files as adjust_strip_files
from ._result import StripResult as StripResult
