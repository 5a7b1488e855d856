"""Fuzzing every reader with hypothesis: mutated real inputs fail only with the reader's own error.

Each reader gets real or realistic inputs (vendor RPC files of every text format, a ground and an
observation table, the metadata files) mutated by truncation, swapped tokens, numbers replaced by
text / NaN / huge values, deleted or repeated lines and inserted random bytes. Whatever the
mutation, the reader either returns a valid result or raises its own error type (``RPCFormatError``,
``TableError``, ``MetadataError``; all ``ValueError``) with the file's path in the message; any
other exception, or an error that does not name the file, fails. Derandomised: the same examples
run everywhere (``FUZZ_EXAMPLES`` per seed file, a few thousand in all).
"""

import pathlib
import re
import tempfile
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxgeo.errors import JaxgeoWarning
from jaxgeo.io import (
    GroundPoints,
    MetadataError,
    Observations,
    RPCFormatError,
    TableError,
    read_dem,
    read_ground,
    read_metadata,
    read_observations,
    read_rpc,
    write_ground,
    write_observations,
    write_rpb,
)
from jaxgeo.models.internal import check_rpc

REAL = pathlib.Path(__file__).parents[1] / "data" / "real"
DATA = pathlib.Path(__file__).parent / "data"
FUZZ_EXAMPLES = 250

NUMBER = re.compile(rb"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
REPLACEMENTS = [
    b"", b"abc", b"nan", b"NaN", b"-inf", b"Infinity", b"1e400", b"-1e999", b"1e308", b"0",
    b"0x1F", b"1_000", b"1,5", b"\xef\xbc\x91\xef\xbc\x92", b"null", b"true", b"[]", b"{}", b'"',
    b"<", b"</x>", b"(", b")", b";", b":", b"=", b"\x00", b"\xff\xfe", b"9" * 400, b"9" * 5000,
    b"[" * 3000,
]  # fmt: skip


@st.composite
def mutations(draw, seed: bytes) -> bytes:
    """One to three mutations of ``seed``."""
    data = seed
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["truncate", "number", "swap", "bytes", "line", "repeat"]))
        if kind == "truncate":
            data = data[: draw(st.integers(0, len(data)))]
        elif kind == "number":
            spans = [m.span() for m in NUMBER.finditer(data)]
            if spans:
                a, b = draw(st.sampled_from(spans))
                data = data[:a] + draw(st.sampled_from(REPLACEMENTS)) + data[b:]
        elif kind == "swap":
            tokens = re.split(rb"(\s+)", data)
            if len(tokens) > 2:
                i, j = draw(st.integers(0, len(tokens) - 1)), draw(st.integers(0, len(tokens) - 1))
                tokens[i], tokens[j] = tokens[j], tokens[i]
                data = b"".join(tokens)
        elif kind == "bytes":
            at = draw(st.integers(0, len(data)))
            data = data[:at] + draw(st.binary(min_size=1, max_size=8)) + data[at:]
        else:
            lines = data.split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            lines[i : i + 1] = [] if kind == "line" else [lines[i], lines[i]]
            data = b"\n".join(lines)
    return data


def _rpb_seed() -> bytes:
    with tempfile.TemporaryDirectory() as d:
        path = pathlib.Path(d) / "x.RPB"
        write_rpb(read_rpc(REAL / "formats" / "rpc_IKONOS.txt"), path)
        return path.read_bytes()


def _table_seeds() -> dict[str, bytes]:
    ground = GroundPoints(
        ("G1", "G2", "C1"),
        np.array([[7.05, 43.72, 10.0], [7.06, 43.71, 120.5], [7.07, 43.70, -3.25]]),
        ("gcp", "gcp", "check"),
        np.full((3, 3), 0.3),
    )
    obs = Observations(
        ("G1", "G1", "G2", "C1"),
        ("left", "right", "left", "right"),
        np.array([[10.5, 20.25], [11.0, 19.5], [300.0, 400.0], [5.0, 6.0]]),
        np.full(4, 0.5),
    )
    with tempfile.TemporaryDirectory() as d:
        write_ground(ground, pathlib.Path(d) / "g.csv")
        write_observations(obs, pathlib.Path(d) / "o.csv")
        return {
            "ground": (pathlib.Path(d) / "g.csv").read_bytes(),
            "obs": (pathlib.Path(d) / "o.csv").read_bytes(),
        }


def _dem_seed() -> bytes:
    """A tiny georeferenced height raster (8 x 8 float32, EPSG:4326), as GeoTIFF bytes."""
    import rasterio
    from rasterio.transform import from_origin

    with tempfile.TemporaryDirectory() as d:
        path = pathlib.Path(d) / "dem.tif"
        profile = dict(driver="GTiff", count=1, height=8, width=8, dtype="float32",
                       crs="EPSG:4326", transform=from_origin(7.0, 44.0, 0.01, 0.01))  # fmt: skip
        with rasterio.open(path, "w", **profile) as dst:
            dst.write(np.arange(64, dtype="float32").reshape(1, 8, 8))
        return path.read_bytes()


def _check_dem(dem, path):
    dem(np.array([[7.02, 43.98]]))  # the cell values are read too


def _check_rpc(rpc, path):
    check_rpc(rpc, str(path))


SEEDS = {
    "rpc_txt": (REAL / "formats" / "rpc_IKONOS.txt", read_rpc, RPCFormatError, _check_rpc),
    "maxar_xml": (REAL / "formats" / "rpc_WV2.xml", read_rpc, RPCFormatError, _check_rpc),
    "dimap_v2": (REAL / "formats" / "rpc_PLEIADES.xml", read_rpc, RPCFormatError, _check_rpc),
    "dimap_v1": (DATA / "PHRDIMAP_P1BP--2018122638935449CP.XML", read_rpc, RPCFormatError,
                 _check_rpc),
    "ossim_geom": (REAL / "phr_ventoux__left_image.geom", read_rpc, RPCFormatError, _check_rpc),
    "json": (DATA / "JAX_068_001_RGB.json", read_rpc, RPCFormatError, _check_rpc),
    "rpb": (None, read_rpc, RPCFormatError, _check_rpc),
    "ground": (None, read_ground, TableError, None),
    "obs": (None, read_observations, TableError, None),
    "meta_txt": (DATA / "cartosat1_stereo_meta.txt", read_metadata, MetadataError, None),
    "meta_json": (DATA / "cartosat1_stereo_meta.json", read_metadata, MetadataError, None),
    "dem": (None, read_dem, ValueError, _check_dem),
}  # fmt: skip


def _seed_bytes(name: str) -> bytes:
    path = SEEDS[name][0]
    if path is not None:
        return path.read_bytes()
    if name == "rpb":
        return _rpb_seed()
    if name == "dem":
        return _dem_seed()
    return _table_seeds()[name]


SUFFIX = {"dem": ".tif", "json": ".json", "meta_json": ".json", "ground": ".csv", "obs": ".csv"}


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


# random bytes with a NUL make a "raster": GDAL then logs undecodable text, which rasterio's
# logging callback cannot print (an unraisable exception inside rasterio, not ours)
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
@pytest.mark.parametrize("name", list(SEEDS))
def test_mutated_input_fails_only_with_the_readers_own_error(fuzz_dir, name):
    _, reader, error, validate = SEEDS[name]
    seed = _seed_bytes(name)
    path = fuzz_dir / f"{name}{SUFFIX.get(name, '.txt')}"
    path.write_bytes(seed)
    reader(path)  # the unmutated seed reads
    outcomes = {"read": 0, "refused": 0}

    @settings(
        max_examples=FUZZ_EXAMPLES,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )
    @given(mutations(seed))
    def check(data):
        path.write_bytes(data)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", JaxgeoWarning)  # warnings are allowed results
            try:
                result = reader(path)
                if validate is not None:  # use what was read (a DEM reads its cells lazily)
                    validate(result, path)
            except error as err:
                assert str(path) in str(err), f"error does not name the file: {err}"
                outcomes["refused"] += 1
                return
        outcomes["read"] += 1

    check()
    print(f"{name}: {outcomes}")
    assert outcomes["refused"] > 0
