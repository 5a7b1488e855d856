"""README's results table, regenerated from the benchmarks' JSON in ``benchmarks/results/``.

    python benchmarks/readme_table.py            # print the table
    python benchmarks/readme_table.py --write    # replace it in README.md (between the markers)

One row per headline figure: what was measured, jaxgeo's number, the peer's in the same run and
the ratio, the machine the JSON names and the date its file was last committed (or modified).
Rerun a benchmark, then this script, and README follows.
"""

from __future__ import annotations

import argparse
import datetime
import json
import pathlib
import subprocess

HERE = pathlib.Path(__file__).resolve().parent
RESULTS = HERE / "results"
README = HERE.parent / "README.md"
MARKER = "<!-- results table -->"


def _load(name: str) -> tuple[dict, str]:
    path = RESULTS / name
    data = json.loads(path.read_text())
    try:
        date = subprocess.run(
            ["git", "log", "-1", "--format=%cs", "--", str(path)],
            capture_output=True, text=True, cwd=HERE, check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        date = ""
    if (
        not date
        or subprocess.run(
            ["git", "diff", "--quiet", "--", str(path)], cwd=HERE, capture_output=True
        ).returncode
    ):
        date = datetime.date.fromtimestamp(path.stat().st_mtime).isoformat()
    machine = data.get("cpu", "")
    devices = data.get("devices")
    if devices:
        machine = f"{machine} ({', '.join(devices)})" if machine else ", ".join(devices)
    return data, f"{machine or '2-core CPU'}, {date}"


def _size(results: list[dict], points: int) -> dict:
    return next(r for r in results if r["points"] == points)


def _ratio(x: float) -> str:
    return f"{x:.0f}x" if x >= 10 else f"{x:.1f}x" if x >= 1 else f"{x:.2f}x"


def _peers(r: dict, ratio: float | None = None) -> tuple[str, str]:
    """The peer and ratio cells of one size: GDAL, then shareloc and rpcm where measured
    (``ratio``: jaxgeo's points/s instead of the row's)."""
    names = [p for p in ("gdal", "shareloc", "rpcm") if f"{p}_points_per_s" in r]
    label = {"gdal": "GDAL", "shareloc": "shareloc", "rpcm": "rpcm"}
    ours = r["jaxgeo_points_per_s"] if ratio is None else ratio
    peer = "; ".join(f"{label[p]} {r[f'{p}_points_per_s'] / 1e6:.1f} M pts/s" for p in names)
    ratios = " / ".join(_ratio(ours / r[f"{p}_points_per_s"]) for p in names)
    return peer, ratios


def rows() -> list[tuple[str, str, str, str, str]]:
    out = []
    proj, where = _load("projection-2core-cpu.json")
    for n in (10_000, 1_000_000, 10_000_000):
        r = _size(proj["results"], n)
        out.append((
            f"`rpc.project`, {n:,} points (numpy in/out)",
            f"{r['jaxgeo_points_per_s'] / 1e6:.0f} M pts/s", *_peers(r), where,
        ))  # fmt: skip
        if n == 1_000_000 and "jaxgeo_one_off_points_per_s" in r:
            once = r["jaxgeo_one_off_points_per_s"]
            out.append((
                f"`rpc.project`, {n:,} points, a size used once (chunked path)",
                f"{once / 1e6:.0f} M pts/s", *_peers(r, once), where,
            ))  # fmt: skip
    loc, where = _load("localization-2core-cpu.json")
    for n in (10_000, 1_000_000):
        r = _size(loc["results"], n)
        out.append((
            f"`rpc.localize`, {n:,} points",
            f"{r['jaxgeo_points_per_s'] / 1e6:.1f} M pts/s", *_peers(r), where,
        ))  # fmt: skip
    cli, where = _load("cli-times-2core-cpu.json")
    for name, r in cli["results"].items():
        out.append((
            f"`jaxgeo {name}` wall time, warm (cold)",
            f"{r['warm_s']:.1f} s ({r['cold_s']:.1f} s)", "", "", where,
        ))  # fmt: skip
    batches = [_load(n) for n in ("batch-10000-l2-2core-cpu.json", "batch-10000-2core-cpu.json")]
    s, where = _load("strip-80-scenes-2core-cpu.json")
    timed = [
        (f"{b['problems']} bias adjustments in one call, {b['loss']}", b["jaxgeo_s"],
         "loop of compiled solves", b["loop_s"], w)
        for b, w in batches
    ] + [(f"strip, {s['scenes']} sub-scenes, both levels", s["jaxgeo_s"],
          "scipy least_squares", s["scipy_s"], where)]  # fmt: skip
    for label, ours, peer, theirs, w in timed:
        out.append((label, f"{ours:.2f} s", f"{peer} {theirs:.1f} s", f"{theirs / ours:.1f}x", w))
    c, where = _load("strip-curve-20-1280-2core-cpu.json")
    big, grow = c["memory"][-1], c["memory_scaling"]
    out.append((
        f"strip, {big['scenes']} sub-scenes, both levels (time per step, memory: growth from "
        f"{c['memory'][0]['scenes']} over linear)",
        f"{big['jaxgeo_s']:.2f} s, {big['peak_bytes'] / 2**20:.0f} MiB "
        f"({grow['time_per_step_growth_over_linear']:.2f}x, "
        f"{grow['peak_growth_over_linear']:.2f}x)", "", "", where,
    ))  # fmt: skip
    a, where = _load("adjust-scale-100k-2core-cpu.json")
    first = next(iter(a["runs"]))
    for loss, r in a["runs"].items():
        cache = "empty cache" if loss == first else f"after {first}, on the cache it left"
        out.append((
            f"`jaxgeo adjust`, {a['case']['observations']} observations, {loss} ({cache})",
            f"{r['wall_s']:.1f} s, {r['peak_rss_mib']:.0f} MiB", "", "", where,
        ))  # fmt: skip
    return out


def table() -> str:
    head = "| measured | jaxgeo | peer, same run | ratio | machine, date |"
    lines = [head, "|---|---|---|---|---|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows()]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="replace the table in README.md")
    args = parser.parse_args()
    text = table()
    if not args.write:
        print(text)
        return
    readme = README.read_text()
    head, found, rest = readme.partition(MARKER)
    _, found2, tail = rest.partition(MARKER)
    if not (found and found2):
        raise SystemExit(f"README.md has no pair of {MARKER!r} markers")
    README.write_text(f"{head}{MARKER}\n{text}\n{MARKER}{tail}")


if __name__ == "__main__":
    main()
