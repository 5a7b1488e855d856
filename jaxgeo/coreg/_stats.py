"""Statistics of a height difference ``dh = DSM - REF`` (metres): the numbers users of DEM
co-registration compare (mean, median, NMAD, RMSE, LE90, cells used)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

NMAD_SCALE = 1.4826
"""1 / Phi^-1(3/4): the NMAD of normal errors equals their standard deviation."""


@dataclass(frozen=True)
class DHStats:
    """Statistics of height differences ``dh`` (m) over ``cells`` finite values.

    ``nmad_m`` = 1.4826 median(|dh - median(dh)|); ``rmse_m`` = sqrt(mean(dh^2)) (the bias
    included); ``le90_m`` = the 90th percentile of |dh| (linear interpolation, numpy's default);
    ``std_m`` = the standard deviation (about the mean, ``ddof=0``). All NaN when ``cells`` is 0.
    """

    mean_m: float
    median_m: float
    nmad_m: float
    rmse_m: float
    le90_m: float
    cells: int
    std_m: float = float("nan")

    def as_dict(self) -> dict[str, float | int]:
        """The fields as a dict (keys as the field names), for JSON."""
        return asdict(self)


def nmad(dh: np.ndarray) -> float:
    """Normalised median absolute deviation of the finite values of ``dh`` (NaN if none)."""
    dh = np.asarray(dh, dtype=np.float64)
    dh = dh[np.isfinite(dh)]
    if dh.size == 0:
        return float("nan")
    return float(NMAD_SCALE * np.median(np.abs(dh - np.median(dh))))


def dh_stats(dh: np.ndarray) -> DHStats:
    """:class:`DHStats` of the finite values of ``dh`` (any shape; NaN and inf are left out)."""
    dh = np.asarray(dh, dtype=np.float64)
    dh = dh[np.isfinite(dh)]
    if dh.size == 0:
        nan = float("nan")
        return DHStats(nan, nan, nan, nan, nan, 0, nan)
    median = float(np.median(dh))
    return DHStats(
        mean_m=float(np.mean(dh)),
        median_m=median,
        nmad_m=float(NMAD_SCALE * np.median(np.abs(dh - median))),
        rmse_m=float(np.sqrt(np.mean(dh * dh))),
        le90_m=float(np.percentile(np.abs(dh), 90.0)),
        cells=int(dh.size),
        std_m=float(np.std(dh)),
    )
