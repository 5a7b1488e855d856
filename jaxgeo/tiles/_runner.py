"""Running a tile plan: a pure per-tile function mapped over the tiles, here or on dask workers.

``work(tile, path)`` computes one tile and writes its result to ``path`` (a temporary name in the
work folder: any format, e.g. a GeoTIFF of the tile's window), returning a small JSON object of
statistics; it returns ``None`` or raises :class:`NoData` for a tile without data (outside the
footprint, no texture, water, clouds: nodata in the product, not an error of the run). It must be
picklable (a module-level function or a dataclass instance) and depend on nothing but its
arguments: a tile may run twice, on any worker.

The runner (:func:`run_tiles`) renames each finished result onto ``<folder>/tiles/<id><suffix>``
and records the tile in ``<folder>/tiles/<id>.json`` (both atomic, on the worker), so a finished
tile is never half-written and a second run on the same folder reuses it (``--resume``):
``<folder>/plan.json`` holds the plan, and a folder of another plan is refused.

Where tiles run (``workers``, ``scheduler``): ``workers=0``, or with ``workers=None`` a small plan
(below :data:`IN_PROCESS_MAX_PX` px) or a machine of fewer than :data:`MIN_CORES_FOR_WORKERS` cores,
runs them one after the other in this process; otherwise an embedded dask.distributed
``LocalCluster`` of ``workers`` (default: one per core) worker processes started with ``spawn`` (JAX
and ``fork`` deadlock), one thread each, that live for the whole run so compiled programs stay warm
(and across runs, XLA's compilation cache on disk, :mod:`jaxgeo._runtime.jaxconfig`).
``scheduler="tcp://host:8786"`` sends the same tasks to an existing dask cluster instead
(dask-jobqueue on SLURM/PBS, dask-kubernetes, ``dask scheduler`` + ``dask worker``; the workers need
jaxgeo installed and the same view of the input files and of the work folder, e.g. a shared file
system). On SLURM, for example::

    dask scheduler --scheduler-file $HOME/sched.json &            # on the login node
    sbatch --array=1-8 --cpus-per-task=16 --wrap \
        "dask worker --scheduler-file $HOME/sched.json --nworkers 16 --nthreads 1"
    jaxgeo ortho scene.tif --dem dem.tif -o ortho.tif --scheduler tcp://login:8786

(or ``dask_jobqueue.SLURMCluster(cores=16, processes=16, memory="64GB").scale(jobs=8)`` in a
Python session that stays open, and its ``scheduler_address``). One single-threaded worker
process per core, as the embedded cluster does: a tile is one core's work.

Faults: a tile whose function raises is retried ``retries`` times, a tile whose worker died is
rescheduled up to ``retries`` times (the embedded cluster's nannies restart dead workers); then
the run stops with a :class:`TileError` naming the tile. Nothing is assembled from a failed run,
and its finished tiles stay in the folder for the next run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import pathlib
import secrets
import threading
import time
from collections.abc import Callable

from .._runtime.progress import Progress
from ..errors import JaxgeoError
from ..io.internal import atomic_output, atomic_write_text
from ._plan import PlanError, Tile, TilePlan, read_plan, write_plan
from ._settings import DEFAULT_RETRIES, TileSettings

IN_PROCESS_MAX_PX = 25_000_000
"""Products up to this many pixels run in this process when ``workers=None``: starting worker
processes (Python, jax, the first compilation in each) costs seconds, more than a small job takes
on one core."""
MIN_CORES_FOR_WORKERS = 3
"""With ``workers=None``, worker processes only on a machine of at least this many cores: on 2
cores a 12 000 px orthoimage (159 Mpx, tiles of ~0.1 s) took 22 s in this process, whose COG
writer already uses both cores, and 26 s on 2 workers (benchmarks/speed/ortho_scene.py)."""
WORKER_XLA_FLAGS = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
"""Each worker process is one core's worth of work: XLA's own thread pools stay single-threaded
so that ``workers`` processes do not fight over the cores."""


_DEFAULT = TileSettings()


class NoData(JaxgeoError):
    """Raised by a tile's work: the tile has no data (nodata in the product, not an error)."""


class TileError(JaxgeoError, RuntimeError):
    """A tile failed (after its retries) or its worker kept dying; the message names the tile."""


@dataclasses.dataclass(frozen=True)
class TileResult:
    """A finished tile: ``id``, ``path`` of its result (``None``: no data), the ``stats`` its work
    returned, the ``seconds`` it took, and whether it was ``reused`` from an earlier run."""

    id: str
    path: pathlib.Path | None
    stats: dict
    seconds: float
    reused: bool = False


@dataclasses.dataclass(frozen=True)
class TileRun:
    """What :func:`run_tiles` did: the work ``folder``, every tile's :class:`TileResult` (plan
    order), the ``workers`` used (0: in this process; a cluster's: its workers), the dask
    ``scheduler`` address (``None``: in this process), and the wall ``seconds``."""

    folder: pathlib.Path
    results: dict[str, TileResult]
    workers: int
    scheduler: str | None
    seconds: float

    @property
    def reused(self) -> int:
        """Tiles taken from an earlier run."""
        return sum(r.reused for r in self.results.values())

    @property
    def empty(self) -> int:
        """Tiles without data."""
        return sum(r.path is None for r in self.results.values())


class _NoOutput(Exception):
    """Internal: the tile has no data; its temporary output is discarded."""


def _marker(folder: pathlib.Path, tile_id: str) -> pathlib.Path:
    return folder / "tiles" / f"{tile_id}.json"


def run_one_tile(work: Callable, tile: Tile, folder: str, suffix: str) -> TileResult:
    """Run ``work`` on ``tile`` and record it in ``folder`` (on a worker, or here)."""
    t0 = time.perf_counter()
    root = pathlib.Path(folder)
    final = root / "tiles" / f"{tile.id}{suffix}"
    stats, path = None, None
    try:
        with atomic_output(final, overwrite=True, suffix=f".tmp{suffix}",
                           leftovers=(".aux.xml",)) as tmp:  # fmt: skip
            try:
                stats = work(tile, tmp)
            except NoData as err:
                stats = {"no_data": str(err)}
                raise _NoOutput from None
            if stats is None:
                stats = {}
                raise _NoOutput
            path = final
    except _NoOutput:
        final.unlink(missing_ok=True)  # a result of an earlier attempt, if any
    seconds = time.perf_counter() - t0
    record = {"id": tile.id, "file": path.name if path else None, "stats": stats,
              "seconds": seconds}  # fmt: skip
    atomic_write_text(_marker(root, tile.id), json.dumps(record) + "\n", overwrite=True)
    return TileResult(tile.id, path, dict(stats), seconds)


def _finished(folder: pathlib.Path, tile: Tile) -> TileResult | None:
    """The tile's result from an earlier run in ``folder``, if it finished."""
    marker = _marker(folder, tile.id)
    try:
        record = json.loads(marker.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if record.get("file") is None:
        return TileResult(tile.id, None, dict(record.get("stats") or {}), 0.0, reused=True)
    path = marker.parent / record["file"]
    if not path.is_file():
        return None
    return TileResult(tile.id, path, dict(record.get("stats") or {}), 0.0, reused=True)


def prepare_folder(plan: TilePlan, folder: str | os.PathLike) -> dict[str, TileResult]:
    """Create ``folder`` (and ``tiles/``) for ``plan`` and return the tiles already finished
    there; a folder holding another plan is a :class:`PlanError`."""
    folder = pathlib.Path(folder)
    (folder / "tiles").mkdir(parents=True, exist_ok=True)
    saved = folder / "plan.json"
    if saved.exists():
        try:
            other = read_plan(saved)
        except PlanError as err:
            raise PlanError(
                f"{folder}: holds a damaged plan ({err}); name another folder"
            ) from None
        if other.fingerprint() != plan.fingerprint():
            raise PlanError(
                f"{folder}: holds the tiles of another {other.kind} job (different inputs, grid "
                "or options); name another folder or remove it"
            )
    else:
        write_plan(plan, saved)
    done = {}
    for tile in plan.tiles:
        found = _finished(folder, tile)
        if found is not None:
            done[tile.id] = found
    return done


def cores() -> int:
    """CPU cores this process may use."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on macOS or Windows
        return max(os.cpu_count() or 1, 1)


def resolve_workers(plan: TilePlan, workers: int | None, scheduler: str | None) -> int:
    """Worker processes to start: 0 (in this process) for ``workers=0``, or with ``workers=None``
    with fewer than :data:`MIN_CORES_FOR_WORKERS` cores or a product of at most
    :data:`IN_PROCESS_MAX_PX` px; else ``workers`` or one per core. With a ``scheduler`` nothing
    is started (the cluster's workers run the tiles)."""
    if workers is not None and workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    if scheduler:
        return 0
    if workers is None:
        n = cores()
        small = plan.width * plan.height <= IN_PROCESS_MAX_PX or len(plan.tiles) < 2
        return 0 if n < MIN_CORES_FOR_WORKERS or small else n
    return int(workers)


class WorkerPool:
    """dask workers for :func:`run_tiles`, started in the background so that their start (new
    processes importing dask, jax and jaxgeo: seconds) overlaps what the caller does meanwhile
    (planning the tiles). ``workers`` processes of an embedded LocalCluster, or the workers of
    the dask cluster at ``scheduler``; ``warm``: modules each worker imports at once. Close it
    (or use it as a context manager) when done."""

    def __init__(self, workers: int = 0, scheduler: str | None = None,
                 retries: int = DEFAULT_RETRIES, warm: tuple[str, ...] = ()):  # fmt: skip
        if not scheduler and workers < 1:
            raise ValueError(f"a worker pool needs workers >= 1 or a scheduler, got {workers}")
        self.workers, self.scheduler, self.retries = int(workers), scheduler, int(retries)
        self._client = self._cluster = self._error = None
        self._closed = False
        self._thread = threading.Thread(target=self._start, args=(tuple(warm),), daemon=True,
                                        name="jaxgeo-workers")  # fmt: skip
        self._thread.start()

    def _start(self, warm: tuple[str, ...]) -> None:
        try:
            from distributed import Client

            if self.scheduler:
                self._client = Client(self.scheduler, timeout="30s", set_as_default=False)
            else:
                self._cluster = _local_cluster(self.workers, self.retries)
                self._client = Client(self._cluster, set_as_default=False)
            if warm:
                self._client.run(_import_modules, warm)
        except BaseException as err:  # reported by client(), in the caller's thread
            self._error = err

    def client(self):
        """The dask client, once the workers are up (:class:`TileError` if they cannot be)."""
        self._thread.join()
        if self._error is not None:
            where = f"the dask scheduler {self.scheduler}" if self.scheduler else "dask workers"
            raise TileError(f"cannot start or reach {where}: {_one_line(self._error)}")
        return self._client

    @property
    def address(self) -> str | None:
        """The scheduler's address (``None`` before the start)."""
        if self.scheduler:
            return self.scheduler
        return None if self._cluster is None else self._cluster.scheduler_address

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._thread.join()
        for thing in (self._client, self._cluster):
            if thing is not None:
                with contextlib.suppress(Exception):
                    thing.close(timeout=10)

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _import_modules(names) -> None:
    import importlib

    for name in names:
        importlib.import_module(name)


def run_tiles(
    plan: TilePlan,
    work: Callable,
    folder: str | os.PathLike,
    settings: TileSettings = _DEFAULT,
    *,
    pool: WorkerPool | None = None,
    suffix: str = ".tif",
) -> TileRun:
    """Run ``work(tile, path)`` on every tile of ``plan`` not yet finished in ``folder``.

    See the module docstring for ``work`` and the folder; ``settings``: where the tiles run
    (``workers``, ``scheduler``: the module docstring), ``retries`` of a failing tile (or of a
    tile whose worker died) before a :class:`TileError`, ``progress`` (the tiles' count, rate
    and ETA on stderr: :class:`~jaxgeo._runtime.progress.Progress`); its ``resume`` and
    ``plan`` are :func:`jaxgeo.tiles.make_product`'s (the folder here is ``folder``).
    ``pool``: workers started earlier (:class:`WorkerPool`, left open), used instead of
    ``workers`` and ``scheduler``.
    """
    workers, scheduler, retries = settings.workers, settings.scheduler, settings.retries
    progress = settings.progress
    t0 = time.perf_counter()
    folder = pathlib.Path(folder)
    done = prepare_folder(plan, folder)
    todo = [t for t in plan.tiles if t.id not in done]
    if pool is not None:
        n = pool.workers
    else:
        n = resolve_workers(plan, workers, scheduler)
    bar = None
    if progress:
        bar = Progress(plan.kind, len(plan.tiles), "tile", initial=len(done))
    address = None
    own = None
    try:
        if not todo:
            pass
        elif pool is None and n == 0 and not scheduler:
            for tile in todo:
                done[tile.id] = _in_process(work, tile, folder, suffix, retries)
                if bar is not None:
                    bar.update(1)
        else:
            if pool is None:
                pool = own = WorkerPool(n, scheduler, retries)
            client = pool.client()
            n = n or len(client.scheduler_info().get("workers", {}))
            _on_dask(client, plan, work, todo, (folder, suffix), retries, done, bar)
            address = pool.address
    finally:
        if bar is not None:
            bar.close()
        if own is not None:
            own.close()
    results = {t.id: done[t.id] for t in plan.tiles}
    return TileRun(folder, results, n, address, time.perf_counter() - t0)


def work_folder(out: str | os.PathLike, resume: str | os.PathLike | None) -> pathlib.Path:
    """The folder of a product's tiles: ``resume`` (kept after an interruption), else a new
    temporary folder beside ``out`` (same file system: the tiles' renames stay atomic)."""
    import tempfile

    if resume is not None:
        return pathlib.Path(resume)
    out = pathlib.Path(out)
    return pathlib.Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tiles", dir=out.parent))


def remove_work(folder: pathlib.Path, created: bool) -> None:
    """Remove the work folder (a temporary one, ``created``), or what the runner wrote in a
    ``resume`` folder after success (the folder itself if that leaves it empty)."""
    import shutil

    if created:
        shutil.rmtree(folder, ignore_errors=True)
        return
    shutil.rmtree(folder / "tiles", ignore_errors=True)
    for path in (folder / "plan.json", *folder.glob("mosaic*.vrt")):
        path.unlink(missing_ok=True)
    try:
        folder.rmdir()
    except OSError:
        pass


def _attempts(retries: int) -> str:
    return f"{retries + 1} attempt" + ("s" if retries else "")


def _in_process(work, tile: Tile, folder: pathlib.Path, suffix: str, retries: int) -> TileResult:
    for attempt in range(retries + 1):
        try:
            return run_one_tile(work, tile, str(folder), suffix)
        except Exception as err:  # noqa: PERF203 - a bounded number of retries
            if attempt == retries:
                raise TileError(
                    f"{tile.describe()} failed after {_attempts(retries)}: "
                    f"{type(err).__name__}: {_one_line(err)}"
                ) from err
    raise AssertionError("unreachable")  # pragma: no cover


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split())[:500]


def _local_cluster(n: int, retries: int):
    """An embedded LocalCluster of ``n`` spawned single-threaded worker processes."""
    import dask
    from distributed import LocalCluster

    flags = " ".join(filter(None, [os.environ.get("XLA_FLAGS", ""), WORKER_XLA_FLAGS]))
    # MALLOC_ARENA_MAX: glibc's per-thread arenas (XLA's threads) held 0.1 GB a worker more,
    # measured on the 12 000 px benchmark (peak RSS of the tree 1.66 -> 1.47 GB)
    # OPENCV_FOR_THREADS_NUM: OpenCV's own pool (SIFT, SGM) one thread too, as XLA's
    env = {"XLA_FLAGS": flags, "XLA_PYTHON_CLIENT_PREALLOCATE": "false", "OMP_NUM_THREADS": "1",
           "MALLOC_ARENA_MAX": "2", "OPENCV_FOR_THREADS_NUM": "1"}  # fmt: skip
    config = {
        "distributed.worker.multiprocessing-method": "spawn",
        "distributed.scheduler.allowed-failures": retries,
        "distributed.worker.daemon": False,
        "distributed.admin.tick.limit": "60s",  # a long tile is not a blocked event loop
        # the statistical profiler samples every thread's stack every 10 ms, under the GIL:
        # measured 2x slower tiles with it
        "distributed.worker.profile.enabled": False,
        # dask's default MALLOC_TRIM_THRESHOLD_ turns off glibc's dynamic mmap threshold: every
        # large array is then fresh pages; measured 1.7x slower tiles. Tiles bound the memory.
        "distributed.nanny.pre-spawn-environ": {
            "OMP_NUM_THREADS": 1,
            "MKL_NUM_THREADS": 1,
            "OPENBLAS_NUM_THREADS": 1,
        },
    }
    with dask.config.set(config):
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                            dashboard_address=None, silence_logs=logging.CRITICAL,
                            env=env, preload=["jaxgeo.tiles._worker"])  # fmt: skip


def _on_dask(client, plan, work, todo, where, retries, done, bar) -> None:
    """Run ``todo`` on the workers of ``client``, each result into ``where = (folder,
    suffix)``."""
    from distributed import as_completed
    from distributed.client import FutureCancelledError

    try:
        from distributed.scheduler import KilledWorker
    except ImportError:  # pragma: no cover - older distributed
        from distributed import KilledWorker

    folder, suffix = where
    token = secrets.token_hex(4)
    futures = {}
    try:
        # the costliest first (dask runs higher priorities first): the workers then finish
        # together on small tiles, not one of them on a large last tile while the others wait
        ranked = sorted(todo, key=lambda t: -t.cost)
        for rank, tile in enumerate(ranked):
            key = f"{plan.kind}-{tile.id}-{token}"
            fut = client.submit(run_one_tile, work, tile, str(folder), suffix, key=key,
                                retries=retries, pure=False,
                                priority=len(ranked) - rank)  # fmt: skip
            futures[fut] = tile
        for fut in as_completed(list(futures), loop=client.loop):
            tile = futures[fut]
            try:
                result = fut.result()
            except KilledWorker as err:
                raise TileError(
                    f"{tile.describe()}: its worker died {retries + 1} time(s) running it "
                    f"(out of memory? {_one_line(err)}); finished tiles are kept in {folder}"
                ) from None
            except FutureCancelledError as err:
                raise TileError(f"{tile.describe()}: cancelled ({_one_line(err)})") from None
            except Exception as err:
                raise TileError(
                    f"{tile.describe()} failed after {_attempts(retries)}: "
                    f"{type(err).__name__}: {_one_line(err)}"
                ) from None
            done[tile.id] = result
            if bar is not None:
                bar.update(1)
    finally:
        for fut in futures:
            fut.cancel()
