"""Test set-up: float64 on, single-threaded XLA CPU intra-op pool, the real test data.

Real files under permissive licences are vendored in ``tests/data/real`` (see its README), so the
suite passes on a bare clone; data that cannot be vendored (the AGPL s2p triplet) is read from
``../shared/data/real`` through the ``shared_data`` fixture, which skips with a reason when absent.
"""

import os
import pathlib

# One full-suite CI run hung for 90 min inside a vmapped, jitted strip call (Monte-Carlo batch)
# on a 2-core machine; XLA CPU's multi-threaded Eigen pool is known to wedge on such vmap graphs
# (https://github.com/PyAutoLabs/PyAutoFit/issues/1528). Single-threaded Eigen avoids it and cost
# nothing measurable here (80-scene two-level call 0.30 s either way). Set before jax starts.
#
# The suite's time is mostly XLA compilation (tens of thousands of small programs, each run a few
# times): LLVM optimisation level 0 without the expensive passes cut the CPU time of
# tests/models/test_bias.py + tests/bundle/test_cartosat.py from 199 s to 148 s (-25 %) with the
# same results to every tolerance asserted. XLA's legacy CPU emitters (no fusion emitters)
# compile the adjustment's program 25 % faster again (the demo's robust solve: 3.7 s -> 2.7 s).
# The library itself only adds the vector width (jaxgeo._runtime.jaxconfig.VECTOR_FLAG); a flag the
# caller already set in XLA_FLAGS wins.
_SUITE_XLA_FLAGS = {
    "xla_cpu_multi_thread_eigen": "false",
    "xla_backend_optimization_level": "0",
    "xla_llvm_disable_expensive_passes": "true",
    "xla_cpu_use_fusion_emitters": "false",
}
# jaxlib 0.11 removed the last flag, and XLA aborts the process on a flag it does not know (seen
# on the GPU machine's jaxlib 0.11.2: every xdist worker died at start-up)
try:
    from importlib.metadata import version as _version

    if tuple(int(v) for v in _version("jaxlib").split(".")[:2]) >= (0, 11):
        del _SUITE_XLA_FLAGS["xla_cpu_use_fusion_emitters"]
except Exception:  # noqa: BLE001  (no jaxlib metadata: keep the flags)
    pass
_xla_flags = os.environ.get("XLA_FLAGS", "")
for _name, _value in _SUITE_XLA_FLAGS.items():
    if _name not in _xla_flags:
        _xla_flags += f" --{_name}={_value}"
os.environ["XLA_FLAGS"] = _xla_flags.strip()

# The persistent compilation cache is off in the suite: a CI machine starts with an empty one, so
# writing every test's programs costs time and pays nothing back, and one full-suite run here
# aborted inside jaxlib's executable serialisation (put_executable_and_time). The cache itself
# is tested in subprocesses (tests/runtime/test_jaxconfig.py).
os.environ.setdefault("JAXGEO_CACHE_DIR", "off")

# Runtime shape/type checks of every jaxgeo function (jaxtyping + beartype), as equinox and
# optimistix test themselves; the hook must be installed before jaxgeo is first imported.
# JAXGEO_TYPECHECK=0 switches it off (e.g. to time a test).
if os.environ.get("JAXGEO_TYPECHECK", "1") != "0":
    from jaxtyping import install_import_hook

    import tests.typecheck  # noqa: F401  (the hook's decorators look it up by this name)

    install_import_hook("jaxgeo", "tests.typecheck.typechecker")

import gc  # noqa: E402

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# jax computes a persistent-cache key (a hash of the serialised program) for every compilation
# whenever this flag is on, even with no cache directory set: pure cost in the suite
jax.config.update("jax_enable_compilation_cache", False)

REPO = pathlib.Path(__file__).resolve().parents[1]
VENDORED_DATA = REPO / "tests" / "data" / "real"
# JAXGEO_REAL_DATA may point at another copy of the real files; one that does not exist (e.g. the
# old ../shared default on a bare clone) falls back to the vendored files, which every clone has
_env_real = os.environ.get("JAXGEO_REAL_DATA")
REAL_DATA = (
    pathlib.Path(_env_real) if _env_real and pathlib.Path(_env_real).is_dir() else VENDORED_DATA
)
SHARED_DATA = pathlib.Path(
    os.environ.get("JAXGEO_SHARED_DATA", REPO.parent / "shared" / "data" / "real")
)


def pytest_configure(config):
    # jaxgeo's own warnings fail a test unless it expects them (pytest.warns or a
    # filterwarnings mark); added here, not in pyproject.toml, because resolving the category
    # imports jaxgeo, which must come after the type-checking hook above
    config.addinivalue_line("filterwarnings", "error::jaxgeo.errors.JaxgeoWarning")


# The longest test files (25-60 s each on a 2-core machine, mostly compilation), run first:
# ``--dist loadfile`` hands files to the xdist workers in collection order, so a long file left
# for the end keeps one worker busy while the other waits.
LONGEST_FIRST = (
    "notebooks/test_notebook_02.py",
    "strip/test_solve.py",
    "notebooks/test_notebook_01.py",
    "bundle/test_transforms.py",
    "models/test_affine3d.py",
    "runtime/test_exported.py",
    "cli/test_adjust.py",
    "notebooks/test_notebook_03.py",
    "bundle/test_physical.py",
    "notebooks/test_notebook_04.py",
    "models/test_kepler.py",
)


def pytest_collection_modifyitems(config, items):
    def rank(item):
        path = item.path.relative_to(REPO / "tests").as_posix()
        return LONGEST_FIRST.index(path) if path in LONGEST_FIRST else len(LONGEST_FIRST)

    items.sort(key=rank)  # stable: the other files, and the tests in a file, keep their order


MAPS_BEFORE_CLEARING = 30_000
RSS_BEFORE_CLEARING_MB = 3_000


def _memory_maps_and_rss_mb() -> tuple[int, float] | None:
    """This process's memory maps and resident memory (MB); ``None`` off Linux."""
    try:
        with open("/proc/self/maps") as f:
            maps = sum(1 for _ in f)
        with open("/proc/self/status") as f:
            rss = next(int(line.split()[1]) for line in f if line.startswith("VmRSS"))
    except (OSError, StopIteration):
        return None
    return maps, rss / 1024


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Free every compiled program after a test module once the process holds many.

    XLA's CPU backend maps ~3 memory regions per compiled executable and jax keeps them all
    alive in its caches; the suite compiles tens of thousands of programs (one module alone
    ~4 000), so a single process reached Linux's ``vm.max_map_count`` (65 530) two thirds of the
    way through and segfaulted inside XLA's compiler (CI run of stop 16). The caches are cleared
    after a module that leaves more than :data:`MAPS_BEFORE_CLEARING` maps or
    :data:`RSS_BEFORE_CLEARING_MB` resident (always where ``/proc`` cannot tell): until then the
    next modules reuse the programs compiled before (the demo's solves, the strips): the full
    suite took 954 s against 985 s clearing after every module (user CPU 29.3 against 30.6
    min; one run each, 2-core AMD EPYC, so within the machine's noise).
    """
    yield
    held = _memory_maps_and_rss_mb()
    if held is None or held[0] > MAPS_BEFORE_CLEARING or held[1] > RSS_BEFORE_CLEARING_MB:
        jax.clear_caches()
        gc.collect()


@pytest.fixture
def finite_differences_on_cpu():
    """The test on the host's CPU device (a GPU machine's default is the GPU): for
    ``check_grads``, whose finite differences test the autodiff rules, not the device. On an
    H100 the float64 rounding put their noise over the tolerances that hold on the CPU (a
    second derivative of 2e-6 read as 0.043 beside 1.2e7 entries, tests/test_geodesy.py; 1.9e-5
    relative in tests/models/test_pushbroom.py, the autodiff values equal on both)."""
    with jax.default_device(jax.local_devices(backend="cpu")[0]):
        yield


@pytest.fixture(scope="session")
def real_data() -> pathlib.Path:
    """The vendored real files (``tests/data/real``, permissive licences)."""
    if not REAL_DATA.is_dir():
        raise FileNotFoundError(f"vendored real test data not found at {REAL_DATA}")
    return REAL_DATA


@pytest.fixture(scope="session")
def shared_data() -> pathlib.Path:
    """``../shared/data/real`` (data that may not be vendored, e.g. the AGPL s2p triplet)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA} (a bare clone has no ../shared)")
    return SHARED_DATA


def rpc_from_rasterio(path):
    """An RPC built from GDAL's own reading of a file (independent of jaxgeo.io)."""
    import rasterio

    from jaxgeo import RPC

    with rasterio.open(path) as src:
        r = src.rpcs
    return RPC.from_vendor(
        line_num=r.line_num_coeff,
        line_den=r.line_den_coeff,
        samp_num=r.samp_num_coeff,
        samp_den=r.samp_den_coeff,
        lon_off=r.long_off,
        lon_scale=r.long_scale,
        lat_off=r.lat_off,
        lat_scale=r.lat_scale,
        height_off=r.height_off,
        height_scale=r.height_scale,
        line_off=r.line_off,
        line_scale=r.line_scale,
        samp_off=r.samp_off,
        samp_scale=r.samp_scale,
    ), r


PLEIADES_TIF = "PHR1B_P_201709281038393_SEN_PRG_FC_178609-001.tif"
REFERENCE_GROUND = (7.048662660737769592, 43.72774839443545858, 0.0)
REFERENCE_IMAGE = (100.0, 200.0)  # GDAL's (100.5, 200.5) minus 0.5


@pytest.fixture(scope="session")
def pleiades(real_data):
    """(RPC, rasterio RPC object) of the real Pleiades scene 178609-001, read by GDAL."""
    return rpc_from_rasterio(real_data / PLEIADES_TIF)


def cube_points(rpc, n, seed=0, fraction=1.0):
    """``n`` uniform random ground points in ``fraction`` of the RPC's validity cube."""
    import numpy as np

    rng = np.random.default_rng(seed)
    u = rng.uniform(-fraction, fraction, (n, 3))
    return np.asarray(rpc.ground_offset) + u * np.asarray(rpc.ground_scale)


def pytest_runtest_logreport(report):
    """With ``JAXGEO_FAILURES_LOG`` set (``.ci/gpu``), each failure is appended to that file as it
    happens (by xdist's controller only): a run stopped by its time limit still says why."""
    path = os.environ.get("JAXGEO_FAILURES_LOG")
    if path and report.failed and "PYTEST_XDIST_WORKER" not in os.environ:
        with open(path, "a") as f:
            f.write(f"=== {report.nodeid} ({report.when})\n{report.longreprtext[-4000:]}\n")
