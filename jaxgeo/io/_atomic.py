"""Atomic, non-destructive file output: write beside the target, then rename over it.

Every file jaxgeo writes goes through this module: :func:`atomic_write_text` /
:func:`atomic_write_bytes` for content in memory, :func:`atomic_output` for writers that need a
path (GDAL/rasterio). A reader never sees a half-written file, a crash leaves the previous content
intact, and an existing file is replaced only when the caller passes ``overwrite=True`` (without
it the finished file is linked into place, which fails if another writer got there first).

:func:`claim_output` claims an output for a whole run before any work starts (a claim file
beside it, created exclusively), so that two runs writing the same new output do not both
compute it and silently replace each other's: the second is refused at once, naming the first.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import datetime
import errno
import json
import os
import pathlib
import secrets
import socket
import time
from collections.abc import Iterable, Iterator, Sequence

from .._runtime import interrupt as _interrupt
from ..errors import JaxgeoError


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
        _commit(tmp, path, overwrite)
    finally:
        for leftover in (tmp, *(tmp.with_name(tmp.name + s) for s in leftovers)):
            if os.path.lexists(leftover):
                os.unlink(leftover)


def _commit(tmp: pathlib.Path, path: pathlib.Path, overwrite: bool) -> None:
    """``tmp`` renamed onto ``path``. Without ``overwrite`` a hard link (which fails on an
    existing name) instead of the rename: a file another writer put at ``path`` since the
    check at the start is refused, not silently replaced. File systems without hard links fall
    back to a last existence check and the rename."""
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)
    except FileExistsError:
        refuse_existing(path)  # (raises: it exists)
        raise
    except OSError as err:  # no hard links here (FAT, some network and FUSE file systems)
        if err.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV,
                             errno.EMLINK, errno.ENOSYS):  # fmt: skip
            raise
        refuse_existing(path)
        os.replace(tmp, path)


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


CLAIM_SUFFIX = ".jaxgeo-claim"
"""The claim file of an output ``OUT`` is ``OUT.jaxgeo-claim``, beside it (:func:`claim_output`)."""


class OutputClaimedError(JaxgeoError, FileExistsError):
    """Another run (alive) claimed the output: two writers would replace each other's file."""


@dataclasses.dataclass(frozen=True)
class OutputClaim:
    """An output claimed by this run (:func:`claim_output`); :meth:`release` it at the end.

    Attributes:
        path: the output claimed.
        file: its claim file (``None``: nothing claimed: its folder cannot be written, which
            the writer itself will then report).
        token: what the claim file holds to tell this claim from another's.
        note: a sentence for the user, or ``""``: a stale claim taken over, or (``overwrite``)
            another live run writing the same output.
    """

    path: pathlib.Path
    file: pathlib.Path | None
    token: str = ""
    note: str = ""

    def release(self) -> None:
        """Remove the claim file, if it is still this claim's (never another run's)."""
        if self.file is None:
            return
        with contextlib.suppress(OSError):
            if _read_claim(self.file).get("token") == self.token:
                os.unlink(self.file)


def _proc_start(pid: int) -> str | None:
    """When process ``pid`` started (Linux: clock ticks since boot, /proc/PID/stat field 22),
    to tell it from a later process given the same pid; ``None`` where unknown."""
    try:
        stat = pathlib.Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[-1].split()[19]  # the fields after the command's name


def _alive(record: dict) -> bool:
    """Whether the run of a claim is still going; a claim of another host counts as alive
    (its processes cannot be seen from here)."""
    if record.get("host") != socket.gethostname():
        return True
    try:
        pid = int(record["pid"])
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        pass
    except (KeyError, TypeError, ValueError, OverflowError):
        return True  # not a claim we can judge: never taken over
    started = record.get("proc_start")
    return started is None or _proc_start(pid) in (None, started)


def _read_claim(file: pathlib.Path) -> dict:
    """The record in a claim file; ``{}`` while its writer has not yet written it."""
    for _ in range(20):
        try:
            record = json.loads(file.read_text(encoding="utf-8") or "null")
        except (ValueError, UnicodeDecodeError):
            record = None
        if isinstance(record, dict):
            return record
        time.sleep(0.01)  # created, not yet written: a moment
    return {}


def _describe(record: dict) -> str:
    if not record:
        return "a run that left no details"
    where = f" on {record['host']}" if record.get("host") != socket.gethostname() else ""
    return (f"pid {record.get('pid')}{where}, {record.get('command', '?')!r}, started "
            f"{record.get('started', '?')}")  # fmt: skip


def _claim_file(path: pathlib.Path) -> pathlib.Path:
    """``path``'s claim file: beside it, or beside its first existing parent folder for an
    output whose folder is yet to be made (an output folder ``a/b/c`` under a new ``a/b``
    claims ``a/b``)."""
    target = path
    while not target.parent.is_dir() and target.parent != target:
        target = target.parent
    return target.with_name(target.name + CLAIM_SUFFIX)


def _take_over(file: pathlib.Path, dead: dict, token: str) -> bool:
    """Remove the claim file of a run that no longer runs; ``False`` if another run took it
    over first (a claim moved aside that is not the dead one is put back)."""
    stale = file.with_name(f"{file.name}.{token}.stale")
    try:
        os.rename(file, stale)
    except FileNotFoundError:
        return False
    if _read_claim(stale).get("token") != dead.get("token"):  # a live one, made meanwhile
        with contextlib.suppress(OSError):
            os.link(stale, file)
        os.unlink(stale)
        return False
    os.unlink(stale)
    return True


def claim_output(path: str | os.PathLike, command: str, overwrite: bool = False) -> OutputClaim:
    """Claim ``path`` (a file or a folder to write) for this run, before any work starts.

    The claim is a file ``<path>.jaxgeo-claim`` created exclusively (``O_CREAT | O_EXCL``), so
    of two runs only one gets it; it holds the run's pid, host, ``command`` and start time
    (UTC). Another run's live claim raises :class:`OutputClaimedError` naming the path and
    that run, unless ``overwrite`` (both runs then write; the one that ends last replaces the
    other's output, and the returned claim's ``note`` says so). A claim left by a process of
    this host that no longer runs (killed) is taken over, with a ``note``. A folder that
    cannot be written is not claimed (the writer reports it). Release the claim at the end
    (:meth:`OutputClaim.release`)."""
    path = pathlib.Path(path)
    file = _claim_file(path)
    token = secrets.token_hex(8)
    record = {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "command": command,
        "started": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M:%S UTC"),
        "proc_start": _proc_start(os.getpid()),
        "token": token,
    }
    note = ""
    for _ in range(10):
        try:
            fd = os.open(file, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            other = _read_claim(file)
            if other and not _alive(other):  # its run was killed: taken over
                if _take_over(file, other, token):
                    note = (f"{path}: took over the claim of an earlier run that no longer "
                            f"runs ({_describe(other)})")  # fmt: skip
                continue
            if overwrite:
                return OutputClaim(path, None, note=(
                    f"{path}: another jaxgeo run is writing it too ({_describe(other)}); with "
                    "--overwrite the run that ends last replaces the other's output"))  # fmt: skip
            raise OutputClaimedError(
                f"{path}: another jaxgeo run is writing this output ({_describe(other)}); wait "
                f"for it to end or name another output (if no such run is going, remove "
                f"{file})"
            ) from None
        except OSError:  # a folder that cannot be written: the writer says so
            return OutputClaim(path, None)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(json.dumps(record))
        return OutputClaim(path, file, token, note)
    raise OutputClaimedError(f"{path}: could not claim it ({file} keeps changing)")
