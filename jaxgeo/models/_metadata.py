"""Scene metadata: the approximate geometry that initialises physical sensor models.

The data type lives with the models that use it (a model never imports a reader); reading and
writing the metadata files is :mod:`jaxgeo.io._metadata`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

SCENE_FLOAT_FIELDS = (
    "flying_height_m",
    "along_track_angle_deg",
    "across_track_angle_deg",
    "focal_length_mm",
    "pixel_size_um",
    "line_time_s",
    "first_line_time_s",
)


@dataclasses.dataclass(frozen=True, eq=False)
class SceneMetadata:
    """Approximate geometry of one scene (file formats: :mod:`jaxgeo.io._metadata`).

    ``corners`` is ``(4, 3)``: ``(lon_deg, lat_deg, h_m)`` of UL ``(x=0, y=0)``, UR
    ``(x=n_cols-1, y=0)``, LR ``(x=n_cols-1, y=n_rows-1)``, LL ``(x=0, y=n_rows-1)``.
    Angles in degrees, along-track ``+`` = forward looking (Cartosat-1 fore +26, aft -5).
    ``first_line_time_s`` is the time of line 0 after the sequence epoch; the fore/aft
    interval of an along-track pair is the difference between the two scenes.
    """

    image_id: str
    n_cols: int
    n_rows: int
    corners: np.ndarray
    flying_height_m: float
    along_track_angle_deg: float
    across_track_angle_deg: float = 0.0
    focal_length_mm: float | None = None
    pixel_size_um: float | None = None
    line_time_s: float | None = None
    first_line_time_s: float = 0.0
    epoch_utc: str | None = None

    def __post_init__(self):
        corners = np.array(self.corners, dtype=float)
        if corners.shape != (4, 3):
            raise ValueError(
                f"scene {self.image_id!r}: corners must have shape (4, 3) (UL, UR, LR, LL x "
                f"lon_deg, lat_deg, h_m), got {corners.shape}"
            )
        if not np.all(np.isfinite(corners)):
            raise ValueError(f"scene {self.image_id!r}: corners must be finite, got {corners}")
        if np.any(np.abs(corners[:, 1]) > 90.0):
            raise ValueError(f"scene {self.image_id!r}: corner latitude outside [-90, 90] deg")
        corners.setflags(write=False)
        object.__setattr__(self, "corners", corners)
        for name in ("n_cols", "n_rows"):
            value = getattr(self, name)
            if int(value) != value or int(value) < 2:
                raise ValueError(
                    f"scene {self.image_id!r}: {name} must be an integer >= 2, got {value}"
                )
            object.__setattr__(self, name, int(value))
        for name in SCENE_FLOAT_FIELDS:
            value = getattr(self, name)
            if value is None:
                continue
            value = float(value)
            if not math.isfinite(value):
                raise ValueError(f"scene {self.image_id!r}: {name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        for name in ("flying_height_m", "focal_length_mm", "pixel_size_um", "line_time_s"):
            value = getattr(self, name)
            if value is not None and value <= 0.0:
                raise ValueError(f"scene {self.image_id!r}: {name} must be positive, got {value}")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, SceneMetadata):
            return NotImplemented
        return all(
            np.array_equal(getattr(self, f.name), getattr(other, f.name))
            if f.name == "corners"
            else getattr(self, f.name) == getattr(other, f.name)
            for f in dataclasses.fields(self)
        )

    __hash__ = None  # mutable-looking array field: not hashable

    @property
    def center(self) -> np.ndarray:
        """Mean of the four corners ``(lon_deg, lat_deg, h_m)`` (a point near the scene centre)."""
        return self.corners.mean(axis=0)

    def corner_pixels(self) -> np.ndarray:
        """``(4, 2)`` image coordinates ``(x, y)`` of the corners, in :attr:`corners` order."""
        c, r = self.n_cols - 1.0, self.n_rows - 1.0
        return np.array([[0.0, 0.0], [c, 0.0], [c, r], [0.0, r]])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary with the field names (corners as nested lists)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out["corners"] = self.corners.tolist()
        return out
