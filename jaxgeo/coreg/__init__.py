"""Co-registration of a DSM onto a reference DEM, and the statistics of their difference.

:class:`NuthKaab` (settings) and :func:`nuth_kaab` fit the horizontal and vertical shift of one
grid onto another (Nuth and Kääb 2011, xDEM's method); :func:`coregister` does it on two
rasters and writes the aligned DSM and the height difference after the alignment
(:class:`HeightDifference`: change detection between two dates); :func:`dh_stats` summarises a
difference (median, NMAD, RMSE, LE90, std) over the stable terrain.
"""

from ._files import coregister as coregister
from ._nuth_kaab import CoregistrationError as CoregistrationError
from ._nuth_kaab import CoregistrationWarning as CoregistrationWarning
from ._nuth_kaab import NuthKaab as NuthKaab
from ._nuth_kaab import nuth_kaab as nuth_kaab
from ._nuth_kaab import shift_heights as shift_heights
from ._result import Coregistration as Coregistration
from ._result import HeightDifference as HeightDifference
from ._stats import DHStats as DHStats
from ._stats import dh_stats as dh_stats
from ._stats import nmad as nmad
