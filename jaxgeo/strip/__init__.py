"""Two-level full-strip adjustment (003_a7d3ea260371d8c5.txt sections 6-9).

``adjust_strip(read_strip("strip.json"))``: ties formed from the sub-scenes' line offsets, one
bundle adjustment of all sub-scenes (level 1), the universal correction of eq. 12-13 from the
GCPs (level 2), reports per sub-scene; ``monte_carlo`` runs a batch in one vmapped call.
"""

from .data import Strip as Strip
from .data import StripFormatError as StripFormatError
from .data import read_strip as read_strip
from .distribution import GCPDistributionWarning as GCPDistributionWarning
from .distribution import check_gcp_distribution as check_gcp_distribution
from .pipeline import Level2Data as Level2Data
from .pipeline import TwoLevelSolution as TwoLevelSolution
from .pipeline import two_level as two_level
from .report import StripReport as StripReport
from .solve import StripResult as StripResult
from .solve import UniversalCorrectionWarning as UniversalCorrectionWarning
from .solve import adjust_individually as adjust_individually
from .solve import adjust_strip as adjust_strip
from .solve import monte_carlo as monte_carlo
from .solve import time_two_level as time_two_level
from .ties import SubScene as SubScene
from .ties import strip_ties as strip_ties
from .universal import UniversalCorrection as UniversalCorrection
from .universal import UniversallyCorrected as UniversallyCorrected
from .universal import fit_universal_correction as fit_universal_correction
