"""Inputs named by a URL: images, RPC files and DEMs read from a web server or object storage
without downloading whole files.

A raster by URL (``https://``, ``http://``, ``s3://``, ``gs://``, or a GDAL virtual path
``/vsicurl/...``, ``/vsis3/...``) is opened by GDAL's virtual file systems (rasterio turns the
scheme into ``/vsicurl/``, ``/vsis3/``, ``/vsigs/``): GDAL reads the header and then only the
blocks a command needs, by HTTP range requests; credentials are GDAL's own (``AWS_*``,
``GS_*``, ``GDAL_HTTP_*`` settings or environment variables). A small text model file (``.geom``,
``.RPB``, ``_RPC.TXT``, DIMAP/Maxar XML, JSON) is read whole by one GET (``http(s)`` only: GDAL
reads rasters, not text files, for Python); the 92 doubles of a GeoTIFF's RPC tag are read by
range requests, bit-exact (GDAL gives them as text rounded to 15 digits).

A URL never goes through :class:`pathlib.Path` (which folds ``//`` into ``/``): it is a
:class:`RemotePath`, which has the parts of a path jaxgeo uses (``name``, ``stem``, ``suffix``,
``parent``, ``/``) and is never an output.
"""

from __future__ import annotations

import contextlib
import io
import os
import pathlib
import posixpath
import urllib.error
import urllib.parse
import urllib.request

SCHEMES = ("http", "https", "s3", "gs")
"""URL schemes read as remote inputs (besides GDAL's own ``/vsi...`` paths)."""
TIMEOUT_S = 60.0
"""Time a server may take to answer one request of jaxgeo's own (text files, RPC tags)."""
BLOCK_BYTES = 16384
"""Smallest range jaxgeo asks for when it reads a remote file's bytes itself (one request
covers a TIFF's header and first IFD in the usual case)."""
URL_GDAL_OPTIONS = {
    # not listing the "directory" of the URL (a request per open, refused by many servers);
    # sidecars are not looked for: a raster's RPC is in its tags (jaxgeo asks again, probing
    # the sidecars, when it is not: see :func:`remote_env`)
    "GDAL_DISABLE_READDIR_ON_OPEN": "EMPTY_DIR",
    "GDAL_HTTP_MAX_RETRY": "3",  # a transient 429/502/503/504 is retried, not fatal
    "GDAL_HTTP_RETRY_DELAY": "1",
}
"""GDAL settings in force while jaxgeo opens a raster by URL (only then; an environment variable
of the same name wins)."""


def is_remote(path) -> bool:
    """Whether ``path`` names a remote input: a :class:`RemotePath`, or a string with one of
    :data:`SCHEMES` (``https://...``) or a GDAL virtual path (``/vsicurl/...``, ``/vsis3/...``;
    ``/vsimem/`` and ``/vsizip/`` of a local archive included: any path only GDAL reads)."""
    if isinstance(path, RemotePath):
        return True
    if not isinstance(path, str):
        return False
    scheme, sep, _ = path.partition("://")
    return (bool(sep) and scheme.lower() in SCHEMES) or path.startswith("/vsi")


def as_path(path: str | os.PathLike) -> pathlib.Path | RemotePath:
    """``path`` as a :class:`RemotePath` when :func:`is_remote`, else a :class:`pathlib.Path`."""
    if isinstance(path, RemotePath):
        return path
    if is_remote(path):
        return RemotePath(path)
    return pathlib.Path(path)


class RemotePath(os.PathLike):
    """A file named by a URL (or a GDAL ``/vsi...`` path): ``os.fspath`` gives the URL as typed
    (rasterio opens it through GDAL's virtual file systems); ``name``, ``stem`` and ``suffix``
    are those of the last segment of the URL's path, its query string dropped (an image's name is
    its stem, as for a file)."""

    __slots__ = ("url",)

    def __init__(self, url: str | RemotePath):
        self.url = url.url if isinstance(url, RemotePath) else str(url)

    def __fspath__(self) -> str:
        return self.url

    def __str__(self) -> str:
        return self.url

    def __repr__(self) -> str:
        return f"RemotePath({self.url!r})"

    def __eq__(self, other) -> bool:
        return isinstance(other, RemotePath) and other.url == self.url

    def __hash__(self) -> int:
        return hash(self.url)

    def __reduce__(self):
        return (RemotePath, (self.url,))

    def _split(self) -> urllib.parse.SplitResult:
        return urllib.parse.urlsplit(self.url)

    @property
    def name(self) -> str:
        return urllib.parse.unquote(posixpath.basename(self._split().path.rstrip("/")))

    @property
    def stem(self) -> str:
        return pathlib.PurePosixPath(self.name).stem if self.name else ""

    @property
    def suffix(self) -> str:
        return pathlib.PurePosixPath(self.name).suffix if self.name else ""

    @property
    def parent(self) -> RemotePath:
        """The URL of the folder (query string dropped)."""
        parts = self._split()
        folder = posixpath.dirname(parts.path.rstrip("/"))
        return RemotePath(urllib.parse.urlunsplit(parts._replace(path=folder, query="")))

    def __truediv__(self, name: str) -> RemotePath:
        parts = self._split()
        path = parts.path.rstrip("/") + "/" + urllib.parse.quote(str(name))
        return RemotePath(urllib.parse.urlunsplit(parts._replace(path=path, query="")))

    def with_name(self, name: str) -> RemotePath:
        return self.parent / name

    def with_suffix(self, suffix: str) -> RemotePath:
        return self.with_name(self.stem + suffix)

    def resolve(self) -> RemotePath:
        return self

    absolute = resolve

    def is_dir(self) -> bool:
        return False  # never an output folder

    def exists(self) -> bool:
        """Whether the server has the file (one ``HEAD`` request, ``http(s)`` only). Other
        schemes cannot be asked without GDAL's credentials and answer ``False``: jaxgeo opens
        a remote input without asking first (GDAL's error names it)."""
        if not self._http():
            return False
        try:
            with _request(self.url, method="HEAD"):
                return True
        except OSError:
            return False

    is_file = exists

    def read_bytes(self) -> bytes:
        """The whole file (one GET; ``http(s)`` only, meant for small text model files)."""
        self._need_http("read a model file")
        with _request(self.url) as response:
            return response.read()

    def read_text(self, encoding: str = "utf-8") -> str:
        return self.read_bytes().decode(encoding)

    def _http(self) -> bool:
        return self._split().scheme.lower() in ("http", "https")

    def _need_http(self, what: str) -> None:
        if not self._http():
            raise OSError(
                f"{self.url}: jaxgeo can {what} by an http(s) URL only (GDAL reads rasters from "
                "s3:// and gs://); give a presigned https:// URL or a local copy"
            )


def _request(url: str, method: str = "GET", headers: dict | None = None):
    """An open ``urllib`` response; an HTTP 404 is ``FileNotFoundError``, any other failure an
    ``OSError``, both naming the URL."""
    request = urllib.request.Request(url, method=method, headers=headers or {})
    try:
        return urllib.request.urlopen(request, timeout=TIMEOUT_S)  # noqa: S310 (http(s) only)
    except urllib.error.HTTPError as err:
        if err.code in (404, 410):
            raise FileNotFoundError(f"{url}: no such file on the server (HTTP {err.code})") from err
        raise OSError(f"{url}: the server answered HTTP {err.code} {err.reason}") from None
    except (urllib.error.URLError, TimeoutError) as err:
        reason = getattr(err, "reason", err)
        raise OSError(f"{url}: cannot be read ({reason})") from None


class RangeReader(io.RawIOBase):
    """A read-only, seekable file over an ``http(s)`` URL: each read is a ``Range`` request
    (at least :data:`BLOCK_BYTES`, the last block kept), so reading a TIFF's tags costs a
    request or two whatever the file's size. A server that ignores ranges (``200``) is refused
    rather than downloaded whole."""

    def __init__(self, url: str):
        super().__init__()
        self.url = url
        self._pos = 0
        self._block = (0, b"")  # (start, bytes) of the last range read
        self._size: int | None = None

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._pos

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        if whence == io.SEEK_SET:
            self._pos = int(offset)
        elif whence == io.SEEK_CUR:
            self._pos += int(offset)
        else:
            raise OSError(f"{self.url}: seeking from the end is not supported")
        return self._pos

    def read(self, size: int = -1) -> bytes:
        if size is None or size < 0:
            raise OSError(f"{self.url}: a remote file is read by ranges, not whole")
        start, data = self._block
        stop = start + len(data)
        at_end = self._size is not None and stop >= self._size  # no more bytes to ask for
        if size and (self._pos < start or (self._pos + size > stop and not at_end)):
            self._fetch(self._pos, max(size, BLOCK_BYTES))
            start, data = self._block
        out = data[self._pos - start : self._pos - start + size] if self._pos >= start else b""
        self._pos += len(out)
        return out

    def readinto(self, buffer) -> int:
        data = self.read(len(buffer))
        buffer[: len(data)] = data
        return len(data)

    def _fetch(self, offset: int, length: int) -> None:
        headers = {"Range": f"bytes={offset}-{offset + length - 1}"}
        with _request(self.url, headers=headers) as response:
            if response.status != 206:
                raise OSError(f"{self.url}: the server does not answer range requests "
                              f"(HTTP {response.status})")  # fmt: skip
            data = response.read(length)
            total = response.headers.get("Content-Range", "").rpartition("/")[2]
        self._size = int(total) if total.isdigit() else None
        self._block = (offset, data)


def open_bytes(path: str | os.PathLike):
    """A binary file object of ``path``: the local file, or a :class:`RangeReader` of an
    ``http(s)`` URL. ``OSError`` for any other remote path (GDAL alone reads those)."""
    if not is_remote(path):
        return open(path, "rb")
    remote = as_path(path)
    remote._need_http("read bytes of a file")
    return RangeReader(remote.url)


def remote_env(path, sidecars: bool = False):
    """A context in which GDAL opens ``path`` by URL with :data:`URL_GDAL_OPTIONS` (a
    ``rasterio.Env``); nothing for a local path. ``sidecars``: GDAL looks for the sidecars of
    the raster (``.RPB``, ``_RPC.TXT``, ``.aux.xml``: a request each) instead of none."""
    if not is_remote(path):
        return contextlib.nullcontext()
    import rasterio

    options = dict(URL_GDAL_OPTIONS)
    if sidecars:
        options["GDAL_DISABLE_READDIR_ON_OPEN"] = "TRUE"  # no listing, but each sidecar probed
    # the user's own settings (environment variables) win: a config option would override them
    return rasterio.Env(**{k: v for k, v in options.items() if k not in os.environ})


def file_id(path: str | os.PathLike) -> dict:
    """What identifies the content of an input file (a tile plan's inputs, to resume only over
    the same files): ``{"path", "bytes", "mtime"}`` of a local file; of a URL, its address
    without the query string (a presigned URL's signature changes, not the file) and the
    server's ``Content-Length`` and ``ETag`` or ``Last-Modified`` (``http(s)``: one ``HEAD``
    request; other schemes: the address only)."""
    if not is_remote(path):
        st = os.stat(path)
        return {"path": str(path), "bytes": st.st_size, "mtime": st.st_mtime}
    remote = as_path(path)
    out = {"path": urllib.parse.urlunsplit(remote._split()._replace(query=""))}
    if remote._http():
        with _request(remote.url, method="HEAD") as response:
            headers = response.headers
        out["bytes"] = int(headers.get("Content-Length", -1))
        out["mtime"] = headers.get("ETag") or headers.get("Last-Modified")
    return out
