"""Atomic, non-destructive file output: write beside the target, then rename over it.

Every file jaxgeo writes goes through this module: :func:`atomic_write_text` /
:func:`atomic_write_bytes` for content in memory, :func:`atomic_output` for writers that need a
path (GDAL/rasterio). A reader never sees a half-written file, a crash leaves the previous content
intact, and an existing file is replaced only when the caller passes ``overwrite=True``.
"""

from __future__ import annotations

import contextlib
import csv
import os
import pathlib
import secrets
from collections.abc import Iterable, Iterator, Sequence

from .._runtime import interrupt as _interrupt


def refuse_existing(path: str | os.PathLike, overwrite: bool = False) -> pathlib.Path:
    """``path`` as a Path; ``FileExistsError`` naming it if it exists and not ``overwrite``."""
    path = pathlib.Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(
            f"{path}: refusing to overwrite an existing file (pass overwrite=True)"
        )
    return path


def _temp_beside(path: pathlib.Path, suffix: str) -> pathlib.Path:
    """A new empty file beside ``path`` with the permissions a plain create gives (0666 less the
    umask; ``tempfile.mkstemp`` would make it 0600, which would become the output's mode)."""
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}{suffix}")
        try:
            os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
            return tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"{path}: could not create a temporary file beside it")


@contextlib.contextmanager
def atomic_output(
    path: str | os.PathLike,
    overwrite: bool = False,
    *,
    suffix: str = ".tmp",
    leftovers: Sequence[str] = (),
) -> Iterator[pathlib.Path]:
    """Context giving a temporary path beside ``path`` that is renamed onto it on success.

    Refuses an existing ``path`` unless ``overwrite`` (checked before anything is written). The
    temporary file exists (empty) when the block starts; on an exception it is removed and
    ``path`` is untouched. ``leftovers`` are suffixes of files a writer may leave beside the
    temporary one (GDAL's ``.aux.xml``), removed either way. ``os.replace`` is atomic on POSIX.
    Once the process was asked to stop (Ctrl-C, SIGTERM: :mod:`jaxgeo._runtime.interrupt`)
    nothing is committed: the block's end raises ``KeyboardInterrupt`` instead.
    """
    path = refuse_existing(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_beside(path, suffix)
    try:
        yield tmp
        _interrupt.check()  # an interruption whose exception was lost commits nothing
        os.replace(tmp, path)
    finally:
        for leftover in (tmp, *(tmp.with_name(tmp.name + s) for s in leftovers)):
            if os.path.lexists(leftover):
                os.unlink(leftover)


def atomic_write_bytes(
    path: str | os.PathLike, data: bytes, overwrite: bool = False
) -> pathlib.Path:
    """Write ``data`` to ``path`` atomically; refuse to replace an existing file by default.

    The data goes to a temporary file in the same directory, is flushed and fsynced, then renamed
    onto ``path`` (see :func:`atomic_output`).
    """
    path = pathlib.Path(path)
    with atomic_output(path, overwrite) as tmp:
        write_bytes(tmp, data)
    return path


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path``, flushed and fsynced (the body of :func:`atomic_write_bytes`,
    for a writer that commits several temporary files together)."""
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def write_csv(
    path: str | os.PathLike, header: Sequence[str], rows: Iterable[Iterable[object]]
) -> None:
    """Write a CSV table to ``path`` (UTF-8, ``\\n`` line ends), its rows formed and written one
    at a time (200 000 rows are never held as one string), flushed and fsynced."""
    with open(path, "w", encoding="utf-8", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(header)
        w.writerows(rows)
        f.flush()
        os.fsync(f.fileno())


def atomic_write_csv(
    path: str | os.PathLike,
    header: Sequence[str],
    rows: Iterable[Iterable[object]],
    overwrite: bool = False,
) -> pathlib.Path:
    """:func:`write_csv` atomically (see :func:`atomic_output`)."""
    path = pathlib.Path(path)
    with atomic_output(path, overwrite) as tmp:
        write_csv(tmp, header, rows)
    return path


def atomic_write_text(path: str | os.PathLike, text: str, overwrite: bool = False) -> pathlib.Path:
    """Text version of :func:`atomic_write_bytes` (UTF-8, newlines as given)."""
    return atomic_write_bytes(path, text.encode("utf-8"), overwrite=overwrite)
