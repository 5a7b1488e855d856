"""Adjusting a strip's files: ``strip.json``, its tables and a DEM in, a
:class:`StripFileAdjustment` out (what ``jaxgeo strip`` runs, in one call).

:func:`adjust_strip_files` reads the strip (:func:`~._delivery.read_strip`), checks the outputs
it is to write (:class:`StripOutputs`) before any computation, runs :func:`adjust_strip` and
returns the result with what was read; :meth:`StripFileAdjustment.write` refits and writes the
RPCs and the report (:func:`~._export.write_strip_outputs`). Warnings stay Python warnings
(:class:`~._distribution.GCPDistributionWarning`, :class:`~._errors.LineOffsetWarning`, ...);
the verdicts a caller acts on are fields: :attr:`StripFileAdjustment.converged`,
:attr:`StripFileAdjustment.poor_fit`.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from collections.abc import Callable
from typing import Any

from .._runtime.progress import Stages
from ..bundle.internal import probe_folder
from ..io import DEM
from ._adjustment import adjust_strip
from ._config import RefitConfig, StripConfig
from ._delivery import Strip, read_strip
from ._errors import ConfigError, Setting
from ._export import (
    RPCFormat,
    format_strip_result,
    strip_output_paths,
    strip_summary,
    write_strip_outputs,
)
from ._result import StripResult


@dataclasses.dataclass(frozen=True)
class StripOutputs:
    """Where and how an adjusted strip is written: the folder ``out`` (created if needed), the
    RPC format (``txt``, ``rpb``, ``geom``, ``dimap``), whether earlier outputs may be replaced
    (an input never is) and the RPC refit grid."""

    out: str | os.PathLike
    rpc_format: RPCFormat = "txt"
    overwrite: bool = False
    refit: RefitConfig = dataclasses.field(default_factory=RefitConfig)

    def targets(self, strip: Strip, inputs=()) -> dict[str, pathlib.Path]:
        """Output file name -> path, checked (:func:`~._export.strip_output_paths`: no input,
        nothing existing without ``overwrite``) and the folder writable
        (:func:`jaxgeo.bundle.probe_folder`)."""
        targets = strip_output_paths(strip, self.out, self.rpc_format, self.overwrite, inputs)
        try:
            probe_folder(pathlib.Path(self.out))
        except PermissionError as err:
            where = str(err).replace("{", "{{").replace("}", "}}")
            raise ConfigError(f"{{0}} {where}", Setting("out")) from None
        return targets


@dataclasses.dataclass(frozen=True)
class StripFileAdjustment:
    """A strip adjusted from its files (:func:`adjust_strip_files`): the
    :class:`~._result.StripResult`, the files read (``inputs``: never written over) and the
    outputs checked for it (``outputs``, or ``None``)."""

    result: StripResult
    inputs: tuple[pathlib.Path, ...]
    outputs: StripOutputs | None = None

    @property
    def converged(self) -> bool:
        """Whether the level-1 bundle adjustment converged."""
        return bool(self.result.report.strip["converged"])

    @property
    def poor_fit(self) -> str:
        """The level-1 :class:`~jaxgeo.bundle.PoorFitWarning` message when the observations
        do not fit the models (``""`` when they do)."""
        return self.result.level1.poor_fit

    def summary(self) -> dict[str, Any]:
        """JSON-ready (:func:`~._export.strip_summary`)."""
        return strip_summary(self.result)

    def format(self) -> str:
        """The text report (:func:`~._export.format_strip_result`)."""
        return format_strip_result(self.result)

    def write(
        self, out: str | os.PathLike | None = None, overwrite: bool = False, **options
    ) -> dict[str, Any]:
        """Refit every sub-scene's RPC to its final model and write it, ``report.json`` and
        ``report.txt`` into ``out`` (default: the :class:`StripOutputs` checked before the
        adjustment; ``options``: ``rpc_format``, ``refit`` of :class:`StripOutputs`), never
        over an input, nor over an existing file unless ``overwrite``. Returns the summary with
        the refit errors and ``written`` (:func:`~._export.write_strip_outputs`)."""
        outputs = self.outputs
        if out is not None or outputs is None:
            outputs = StripOutputs(out, overwrite=overwrite, **options)
        targets = outputs.targets(self.result.strip, self.inputs)
        return write_strip_outputs(
            self.result, targets, outputs.refit, outputs.rpc_format, outputs.overwrite
        )


def adjust_strip_files(
    strip: str | os.PathLike | Strip,
    config: StripConfig | None = None,
    *,
    ground: str | os.PathLike | None = None,
    observations: str | os.PathLike | None = None,
    outputs: StripOutputs | None = None,
    progress: Callable[[str], None] | None = None,
) -> StripFileAdjustment:
    """Read a strip (its folder or ``strip.json``, with ``ground``/``observations`` tables
    other than those beside it; or a :class:`~._delivery.Strip` already read), check
    ``outputs`` before any computation, and adjust it (:func:`adjust_strip` with ``config``:
    a DEM of ``config.ties.height`` is among the inputs, never written over). ``progress``:
    called with a line of text before the adjustment. Write the result with
    :meth:`StripFileAdjustment.write`."""
    config = StripConfig() if config is None else config
    if not isinstance(strip, Strip):
        strip = read_strip(strip, ground, observations)
    inputs = [*(strip.files.all() if strip.files is not None else ())]
    dem = config.ties.height
    inputs += [dem.path] if isinstance(dem, DEM) else []
    if outputs is not None:  # before any computation
        outputs.targets(strip, inputs)
    stages = Stages(progress)  # the adjustment's line, then the time it took
    stages(f"adjusting {len(strip.names)} sub-scenes: tie points, level-1 bundle adjustment "
           "and snooping, level-2 correction (the first run of a strip shape compiles, up to a "
           "minute)")  # fmt: skip
    result = adjust_strip(strip, config)
    stages.done(f"adjusted {len(strip.names)} sub-scenes")
    return StripFileAdjustment(result, tuple(pathlib.Path(p) for p in inputs), outputs)
