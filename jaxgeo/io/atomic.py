"""Atomic, non-destructive file output: write beside the target, then rename over it."""

from __future__ import annotations

import os
import pathlib
import tempfile


def atomic_write_bytes(
    path: str | os.PathLike, data: bytes, overwrite: bool = False
) -> pathlib.Path:
    """Write ``data`` to ``path`` atomically; refuse to replace an existing file by default.

    The data goes to a temporary file in the same directory, is flushed and fsynced, then renamed
    onto ``path`` (``os.replace`` is atomic on POSIX): a reader never sees a half-written file, and
    a crash leaves the previous content intact.
    """
    path = pathlib.Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(
            f"{path}: refusing to overwrite an existing file (pass overwrite=True)"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        # mkstemp makes 0600 files; outputs get the usual permissions (0666 less the umask)
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str, overwrite: bool = False) -> pathlib.Path:
    """Text version of :func:`atomic_write_bytes` (UTF-8, newlines as given)."""
    return atomic_write_bytes(path, text.encode("utf-8"), overwrite=overwrite)
