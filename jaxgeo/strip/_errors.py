"""Errors and warnings of the strip adjustment; every message names the file, scene or setting.

A :class:`ConfigError` names the settings at fault as :class:`Setting` items, not as text, so
that each front end says them in its own words: the library writes ``degree='affine'``, the
``jaxgeo strip`` command ``--degree affine`` (:meth:`ConfigError.render`), and no caller has to
rewrite a message.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

from ..errors import JaxgeoError, JaxgeoWarning

_UNSET = object()


@dataclasses.dataclass(frozen=True)
class Setting:
    """One configuration setting, by its path in :class:`~._config.StripConfig` (e.g.
    ``"level2.degree"``), optionally with the value a message proposes or rejects."""

    path: str
    value: Any = _UNSET

    @property
    def name(self) -> str:
        return self.path.rsplit(".", 1)[-1]

    def __str__(self) -> str:
        return self.name if self.value is _UNSET else f"{self.name}={self.value!r}"

    @property
    def has_value(self) -> bool:
        return self.value is not _UNSET


class StripFormatError(JaxgeoError, ValueError):
    """A strip description that cannot be used; the message names the file and scene."""


class ConfigError(JaxgeoError, ValueError):
    """A strip configuration that cannot be used.

    ``template`` is the message with ``{0}``, ``{1}``... where ``settings`` (:class:`Setting`)
    are named; ``str(err)`` names them as the library's configuration fields do.
    """

    def __init__(self, template: str, *settings: Setting):
        self.template = template
        self.settings = tuple(settings)
        super().__init__(self.render())

    def render(self, names: Mapping[str, Callable[[Setting], str]] | None = None) -> str:
        """The message with every setting named by ``names[setting.path]`` (default
        ``str(setting)``): a command-line front end passes its flag names."""
        names = names or {}
        return self.template.format(*(names.get(s.path, str)(s) for s in self.settings))

    def __reduce__(self):
        return (type(self), (self.template, *self.settings))


class UniversalCorrectionWarning(JaxgeoWarning):
    """The chosen universal correction predicts GCP scenes left out worse than a simpler one."""


class LineOffsetWarning(JaxgeoWarning):
    """The vendor RPCs of adjacent sub-scenes disagree at their formed ties by far more than at
    the strip's other seams: a sub-scene's line offset (``first_line``) is probably wrong. Its
    ties are all shifted alike, so the sub-scene's bias absorbs them (nothing for the data
    snooping to find unless it has GCPs): fix the offset in the strip description."""


class MeasuredTieWarning(JaxgeoWarning):
    """Points of the observations without ground coordinates (measured tie points) that cannot
    be used, e.g. measured in one sub-scene only; the message names them and the file."""
