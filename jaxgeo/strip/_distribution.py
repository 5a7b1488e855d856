"""The GCP distribution rule of 003_a7d3ea260371d8c5.txt section 9, checked before solving.

"At least every fourth image should have GCPs and overall at least one sub scene of top 3 and
bottom 3 each should have control points. Otherwise, a curved effect is seen." For a strip of
40 scenes: a GCP scene among 1-3, among 4-7, among 8-11, ... and among 38-40.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence

from ..errors import JaxgeoWarning


class GCPDistributionWarning(JaxgeoWarning):
    """The strip's GCPs do not follow the distribution rule of 003_ section 9."""


@dataclasses.dataclass(frozen=True)
class DistributionCheck:
    """Result of :func:`check_gcp_distribution`; scene numbers are 0-based indices."""

    n_scenes: int
    gcp_scenes: tuple[int, ...]
    gaps: tuple[tuple[int, int], ...]
    """Inclusive index ranges of four (or more) consecutive scenes without any GCP."""
    missing_head: bool
    """No GCP in the first three scenes."""
    missing_tail: bool
    """No GCP in the last three scenes."""

    @property
    def ok(self) -> bool:
        return not (self.gaps or self.missing_head or self.missing_tail)

    def message(self, names: Sequence[str] | None = None) -> str:
        """A sentence naming every gap, using scene ``names`` when given."""

        def name(i: int) -> str:
            return names[i] if names is not None else f"scene {i}"

        parts = []
        if self.missing_head:
            parts.append(
                f"no GCP in the first three scenes ({name(0)}..{name(min(2, self.n_scenes - 1))})"
            )
        if self.missing_tail:
            lo = max(0, self.n_scenes - 3)
            parts.append(f"no GCP in the last three scenes ({name(lo)}..{name(self.n_scenes - 1)})")
        for lo, hi in self.gaps:
            parts.append(f"{hi - lo + 1} consecutive scenes without GCP ({name(lo)}..{name(hi)})")
        if not parts:
            return "GCP distribution follows the rule (a GCP scene in every run of four)"
        return (
            "GCP distribution breaks the rule of 003_ section 9 (expect a curved residual "
            "along the strip): " + "; ".join(parts)
        )


def check_gcp_distribution(
    n_scenes: int,
    gcp_scenes: Sequence[int],
    names: Sequence[str] | None = None,
    warn: bool = True,
) -> DistributionCheck:
    """Check the rule; with ``warn`` emit a :class:`GCPDistributionWarning` naming the gaps."""
    if n_scenes < 1:
        raise ValueError(f"a strip needs at least one scene, got {n_scenes}")
    has = [False] * n_scenes
    for i in gcp_scenes:
        if not 0 <= int(i) < n_scenes:
            raise ValueError(f"GCP scene index {i} outside the strip of {n_scenes} scenes")
        has[int(i)] = True
    gaps = []
    run_start = None
    for i in range(n_scenes + 1):
        if i < n_scenes and not has[i]:
            run_start = i if run_start is None else run_start
            continue
        if run_start is not None and i - run_start >= 4:
            gaps.append((run_start, i - 1))
        run_start = None
    result = DistributionCheck(
        n_scenes=n_scenes,
        gcp_scenes=tuple(sorted({int(i) for i in gcp_scenes})),
        gaps=tuple(gaps),
        missing_head=not any(has[:3]),
        missing_tail=not any(has[-3:]),
    )
    if warn and not result.ok:
        warnings.warn(result.message(names), GCPDistributionWarning, stacklevel=2)
    return result
