"""The outcomes of a solve as data (jit and vmap safe, optimistix style): :class:`RESULTS`,
raised only with ``throw=True``."""

from __future__ import annotations

import optimistix as optx


class RESULTS(optx.RESULTS):  # pyright: ignore
    """Outcomes of :func:`jaxgeo.lsq.solve`: optimistix' and lineax' own, plus the
    engine's. ``RESULTS[result]`` is the message; under ``vmap`` each problem has its own."""

    undetermined = (
        "The normal equations are singular: some parameters or ground points are not "
        "determined (add GCPs or tie points, or choose fewer adjustable parameters)."
    )
    outside_domain = "Ground or image points lie outside the validity domain of a sensor model."
    not_converged = (
        "The bundle adjustment did not converge: the maximum number of steps was reached."
    )


def describe(result: RESULTS) -> tuple[bool, str]:
    """``(converged, short message)`` of a (concrete, unbatched) result, for reports."""
    if bool(result == RESULTS.successful):
        return True, "converged"
    for item, text in (
        (RESULTS.not_converged, "maximum number of steps reached"),
        (RESULTS.nonlinear_max_steps_reached, "maximum number of steps reached"),
        (RESULTS.nonfinite, "non-finite values"),
        (RESULTS.nonlinear_divergence, "non-finite values"),
        (RESULTS.undetermined, "singular normal equations"),
        (RESULTS.outside_domain, "outside the validity domain"),
    ):
        if bool(result == item):
            return False, text
    return False, "solver failed"
