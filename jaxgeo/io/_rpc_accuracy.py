"""The accuracy a vendor states for its RPC: NITF RPC00B ``ERR_BIAS`` and ``ERR_RAND``.

RPC00B carries, beside the 90 numbers of the model, two error estimates in metres:

- ``ERR_BIAS``: the RMS bias error per horizontal axis of all the points of the image (the
  pointing error the whole image shares: what an adjustment with GCPs removes);
- ``ERR_RAND``: the RMS random error per horizontal axis of each point (what varies within the
  image).

Formats carry them under these names (:data:`~jaxgeo.io._rpc_keys.ERROR_KEYS`): ``_RPC.TXT``
and GDAL metadata ``ERR_BIAS``/``ERR_RAND`` (Ikonos writes ``ERR_BIAS: 0003.31 meters``),
``.RPB`` ``errBias``/``errRand``, DigitalGlobe/Maxar XML ``<ERRBIAS>``/``<ERRRAND>``, OSSIM
``.geom`` ``bias_error``/``rand_error``, the GeoTIFF RPC tag's first two doubles, GDAL-named
JSON keys. Airbus DIMAP has no such fields: its ``ERR_BIAS_ROW``/``ERR_BIAS_COL`` (pixels) and
``ERR_BIAS_X``/``ERR_BIAS_Y`` (degrees) are the fit errors of the rational functions against
the physical model (thousandths of a pixel), not the pointing accuracy, and are not read as
such. Unknown is ``-1`` (GDAL, RPB, jaxgeo's writers) and, in practice, ``0``: OSSIM/OTB and
GDAL write 0 where their source had no value (the Pleiades ``.geom`` files OTB makes), and no
delivered model is exact. Both are read as unknown (``None``).

The values are metadata beside the model (:attr:`jaxgeo.io.SensorImage.vendor_accuracy`), not
part of its JAX math: :func:`jaxgeo.stereo.make_dsm` turns them into the a priori orientation
sigma of its ``height_sigma`` band for models that were not adjusted.
"""

from __future__ import annotations

import dataclasses
import math

from ._rpc_common import Lookup, parse_value


@dataclasses.dataclass(frozen=True)
class RPCAccuracy:
    """The accuracy an RPC's vendor states: ``bias_m`` (``ERR_BIAS``) and ``rand_m``
    (``ERR_RAND``), metres RMS per horizontal axis on the ground, ``None`` when unknown;
    ``source`` names the file (for messages)."""

    bias_m: float | None = None
    rand_m: float | None = None
    source: str = ""

    @property
    def known(self) -> bool:
        """Whether the vendor stated either value."""
        return self.bias_m is not None or self.rand_m is not None

    @property
    def horizontal_m(self) -> float | None:
        """The RMS error (m) per horizontal axis of a point: ``ERR_BIAS`` and ``ERR_RAND`` in
        quadrature (an unknown one left out); ``None`` when neither is known."""
        if not self.known:
            return None
        return math.hypot(self.bias_m or 0.0, self.rand_m or 0.0)

    def describe(self) -> str:
        """``"vendor ERR_BIAS 3.31 m, ERR_RAND 0.5 m"`` (the known values), or ``"unknown"``."""
        parts = [f"{name} {value:g} m" for name, value in (("ERR_BIAS", self.bias_m),
                 ("ERR_RAND", self.rand_m)) if value is not None]  # fmt: skip
        return "vendor " + ", ".join(parts) if parts else "unknown"


UNKNOWN = RPCAccuracy()
"""No stated accuracy (a format without the fields, or ``-1``/``0`` in them)."""


def stated_value(value: float) -> float | None:
    """A vendor's ``ERR_BIAS``/``ERR_RAND`` (m) as read: ``None`` for unknown (``-1``, ``0``,
    any value <= 0)."""
    return float(value) if value > 0.0 else None


def read_accuracy(
    keys: tuple[str, str] | None, lookup: Lookup, source: str, units: bool = False
) -> RPCAccuracy:
    """The :class:`RPCAccuracy` of a file whose keys ``(bias, rand)`` are found by ``lookup``
    (:data:`~jaxgeo.io._rpc_common.Lookup`; ``None``: the format has no such keys). An empty
    value is unknown; a value that is not a number is an :class:`RPCFormatError` naming the
    file and the key (a corrupt file, as any other bad value in it). ``units``: a trailing
    unit word is allowed (``0003.31 meters``)."""
    if keys is None:
        return dataclasses.replace(UNKNOWN, source=source)
    values = []
    for key in keys:
        found = lookup(key)
        if found is None or not found[1].strip():
            values.append(None)
            continue
        where, text = found
        values.append(stated_value(parse_value(text, source, where, units)))
    return RPCAccuracy(values[0], values[1], source)


__all__ = ["UNKNOWN", "RPCAccuracy", "read_accuracy", "stated_value"]
