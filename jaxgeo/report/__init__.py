"""Reports a person reads: one self-contained HTML page per product, with its figures.

``jaxgeo adjust|strip|dsm|coregister|ortho --report`` write them; each is one library call:
:func:`write_adjustment_report`, :func:`write_strip_report`, :func:`write_dsm_report`,
:func:`write_coregistration_report`, :func:`write_ortho_report`. A page embeds its figures
(PNG ``data:`` URIs), its style inline, no script and nothing fetched: it opens offline, mailed
as one file. Figures are drawn with matplotlib (Agg, imported only when a report is made), about
900 px wide, with units on every axis and colour bar. Rasters are read decimated to a screen's
size, never whole. Pages are written atomically, an existing one only with ``overwrite``.
Where a raster product's report goes: :func:`report_beside` (``dsm.tif`` ->
``dsm.report.html``); an adjustment's is ``report.html`` in its output folder.
"""

from ._adjustment import write_adjustment_report as write_adjustment_report
from ._adjustment import write_strip_report as write_strip_report
from ._coreg import write_coregistration_report as write_coregistration_report
from ._dsm import write_dsm_report as write_dsm_report
from ._ortho import write_ortho_report as write_ortho_report
from ._page import report_beside as report_beside
