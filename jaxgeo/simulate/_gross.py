"""Gross-error detection against the truth of a simulation: recall and precision of the flags.

A flagged unit is a tie point (all its rays: which one is wrong cannot be told), an image
measurement ``(point id, image)``, or a GCP's coordinates; a GCP's coordinates flag counts as
right when a measurement of that GCP is wrong (the two cannot be told apart either).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple


class FlagScores(NamedTuple):
    """``recall``: share of the corrupted units flagged; ``precision``: share of the flags that
    are right; ``n_flagged``: flagged units."""

    recall: float
    precision: float
    n_flagged: int


def flag_scores(
    flagged: Iterable[Mapping[str, Any]],
    bad_obs: set[tuple[str, str]],
    bad_ties: set[str],
) -> FlagScores:
    """Score ``flagged`` (``gross_errors.flagged`` of an adjustment: dicts with ``id``,
    ``what``, ``image``) against the corrupted measurements ``bad_obs`` ``{(point id, image)}``
    and tie points ``bad_ties`` ``{tie id}``."""
    units = set()
    for f in flagged:
        if f["id"].startswith("tie_"):
            units.add(("tie", f["id"]))
        elif f["what"] == "image":
            units.add((f["id"], f["image"]))
        else:
            units.add(("gcp", f["id"]))
    truth = {("tie", t) for t in bad_ties} | set(bad_obs)
    bad_points = {p for p, _ in bad_obs}
    right = [u for u in units if u in truth or (u[0] == "gcp" and u[1] in bad_points)]
    recall = len(truth & units) / len(truth) if truth else 1.0
    return FlagScores(recall, len(right) / max(len(units), 1), len(units))
