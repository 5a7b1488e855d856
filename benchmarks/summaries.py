"""Markdown tables of one result's JSON, per study, for benchmarks/README.md (``report``).

``SUMMARIES[study](data)`` returns the Markdown lines of one result; a study without an entry
gets :func:`generic` (its top-level numbers and strings). Missing keys (a result written by an
earlier version of its study) leave cells empty rather than failing.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable

DASH = "–"


def num(x, digits: int = 3) -> str:
    """``x`` to ``digits`` significant digits (``–`` for a missing value)."""
    if x is None:
        return DASH
    if isinstance(x, bool) or not isinstance(x, int | float):
        return str(x)
    if x == 0:
        return "0"
    if 1e-3 <= abs(x) < 1e5:
        text = f"{x:.{digits}g}"
        return f"{int(float(text)):,}" if abs(x) >= 10**digits else text
    return f"{x:.{max(digits - 1, 1)}e}"


def seconds(x) -> str:
    return DASH if x is None else f"{num(x)} s"


def ratio(x) -> str:
    """A time ratio: ``162x``, ``4.1x``, ``0.75x``."""
    if x is None:
        return DASH
    return f"{x:.0f}x" if x >= 10 else f"{x:.1f}x" if x >= 1 else f"{x:.2f}x"


def mpts(x) -> str:
    """Points per second in millions: ``551``, ``13.2``, ``0.45``."""
    if x is None:
        return DASH
    m = x / 1e6
    return f"{m:.0f}" if m >= 100 else f"{m:.1f}" if m >= 1 else f"{m:.2f}"


def ms(x) -> str:
    return DASH if x is None else f"{num(x * 1e3)} ms"


def mib(x) -> str:
    return DASH if x is None else f"{num(x / 2**20)} MiB"


def table(head: list[str], rows: list[list[str]]) -> list[str]:
    """A Markdown table (``|`` in cells escaped)."""

    def line(cells):
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"

    return [line(head), "|" + "---|" * len(head), *(line(r) for r in rows)]


# --- rpc.project / rpc.localize: one row per size --------------------------------------------

IMPLEMENTATIONS = {
    "jaxgeo": "jaxgeo",
    "jaxgeo_one_off": "jaxgeo, sizes used once",
    "monomial_jit": "former monomial kernel (jit)",
    "numpy": "numpy",
    "gdal": "GDAL",
    "shareloc": "shareloc",
    "rpcm": "rpcm",
}


def points(data: dict) -> list[str]:
    """projection / localization: points/s of each implementation per size (M points/s, the
    peers' with jaxgeo's ratio to them), then their agreement."""
    rows = data.get("results", [])
    names = [k for k in IMPLEMENTATIONS if any(f"{k}_points_per_s" in r for r in rows)]
    speed = []
    for r in rows:
        cells = [f"{r['points']:,}"]
        for k in names:
            v = r.get(f"{k}_points_per_s")
            cell = mpts(v)
            if v is not None and f"ratio_vs_{k}" in r:
                cell += f" ({ratio(r[f'ratio_vs_{k}'])})"
            cells.append(cell)
        speed.append(cells)
    out = [
        "M points/s (in parentheses: jaxgeo's speed over the peer's, same run):",
        "",
        *table(["points", *(IMPLEMENTATIONS[k] for k in names)], speed),
    ]
    pattern = re.compile(r"^(max_diff_vs_\w+|max_reprojection_px_\w+|converged_fraction|"
                         r"fraction_of_bound)$")  # fmt: skip
    keys = list(dict.fromkeys(k for r in rows for k in r if pattern.match(k)))
    if keys:
        out += ["", *table(["points", *(f"`{k}`" for k in keys)],
                           [[f"{r['points']:,}"] + [num(r.get(k), 2)
                                                                       for k in keys]
                                               for r in rows])]  # fmt: skip
    return out


def batch(d: dict) -> list[str]:
    return table(
        ["problems", "loss", "bias", "jaxgeo, one call", "loop of compiled solves", "ratio",
         "steps mean / max", "converged", "compile"],
        [[f"{d['problems']:,}", d.get("loss", DASH), d.get("bias", DASH), seconds(d["jaxgeo_s"]),
          f"{seconds(d['loop_s'])} ({d.get('loop_measured', DASH)} timed, scaled)",
          ratio(d.get("ratio")), f"{num(d.get('steps_mean'))} / {d.get('steps_max', DASH)}",
          f"{d.get('converged', DASH):,}", seconds(d.get("compile_s"))]],
    )  # fmt: skip


def localize_dem(d: dict) -> list[str]:
    """``localize_on_dem`` (``dem``) and the robust search alone (``dem_before``) against
    ``localize`` at a constant height, per model and size (same run)."""
    rows = [[r["model"], f"{r['points']:,}", ms(r["cases"]["localize"]["best_s"]),
             ms(r["cases"]["dem"]["best_s"]), ratio(r["cases"]["dem"]["ratio_vs_localize"]),
             ms(r["cases"]["dem_before"]["best_s"]),
             ratio(r["cases"]["dem_before"]["ratio_vs_localize"]),
             seconds(r["cases"]["dem"]["first_s"]), seconds(r["cases"]["dem_before"]["first_s"]),
             str(r["same_status"]), num(r["left_to_robust_fraction"], 2),
             f"{num(r['max_diff_vs_before_deg'], 2)} / {num(r['max_diff_vs_before_m'], 2)}"]
            for r in d["results"]]  # fmt: skip
    return table(
        [
            "model",
            "points",
            "localize",
            "dem",
            "dem / localize",
            "before",
            "before / localize",
            "dem first call",
            "before first call",
            "same statuses",
            "left to robust",
            "max diff deg / m",
        ],
        rows,
    )


def cli_times(d: dict) -> list[str]:
    rows = [[f"`jaxgeo {name}`", seconds(r.get("cold_s")), seconds(r.get("warm_s")),
             seconds(r.get("off_s"))] for name, r in d["results"].items()]  # fmt: skip
    load = ", ".join(f"{x:.1f}" for x in d.get("load_average", []))
    return [
        *table(["command", "cold (empty cache)", "warm (best)", "cache off"], rows),
        "",
        f"Strip of {d.get('scenes', DASH)} sub-scenes; load average {load or DASH}.",
    ]


def adjust_scale(d: dict) -> list[str]:
    c = d["case"]
    rows = [[loss, seconds(r.get("wall_s")), f"{num(r.get('peak_rss_mib'))} MiB",
             r.get("steps", DASH), r.get("converged", DASH), num(r.get("s0")),
             f"{r.get('removed', DASH):,}", num(r.get("recall")), num(r.get("recall_detectable")),
             r.get("clean_flagged", DASH)] for loss, r in d["runs"].items()]  # fmt: skip
    cache = "an empty compilation cache" if c.get("fresh_compilation_cache") else "a warm cache"
    return [
        f"{c['ties']:,} ties, {c['observations']:,} observations, {c['gcps']} GCPs, "
        f"{c['gross']:,} gross errors ({c['detectable']:,} detectable); the first loss on "
        f"{cache}, the others on the cache it left.",
        "",
        *table(["loss", "wall", "peak RSS", "steps", "converged", "s0", "removed",
                "recall", "recall, detectable", "clean flagged"], rows),
    ]  # fmt: skip


STRIP_PEERS = {
    "scipy": "scipy least_squares",
    "scipy_2point": "scipy least_squares, 2-point",
    "scipy_analytic": "scipy least_squares, analytic Jacobian",
    "ceres": "Ceres (pyceres)",
}


def strip(d: dict) -> list[str]:
    out = [
        f"{d['scenes']} sub-scenes, {d['tie_points']:,} tie points, {d['unknowns']:,} unknowns; "
        f"check RMS (plan) {num(d.get('direct_absolute_rms_m'))} m (vendor RPCs) -> "
        f"{num(d.get('absolute_rms_m'))} m; tie gap RMS {num(d.get('direct_relative_rms_m'))} m "
        f"-> {num(d.get('relative_rms_m', 0) * 1e3)} mm.",
        "",
    ]
    settings = d.get("peer_settings", {})
    rows = [["jaxgeo, both levels, one compiled call", seconds(d["jaxgeo_s"]), "1x",
             d.get("jaxgeo_status", DASH), DASH, DASH]]  # fmt: skip
    for key, label in STRIP_PEERS.items():
        if d.get(f"{key}_s") is None:
            continue
        rows.append([
            f"{label} ({settings[key]})" if key in settings else label,
            seconds(d[f"{key}_s"]), ratio(d.get(f"{key}_over_jaxgeo")),
            d.get(f"{key}_status", DASH), num(d.get(f"{key}_cost_rel_to_jaxgeo"), 2),
            num(d.get(f"{key}_vs_jaxgeo_px_max"), 2),
        ])  # fmt: skip
    out += table(["level 1 solved by", "time", "vs jaxgeo", "status", "cost rel. to jaxgeo",
                  "largest difference to jaxgeo (px)"], rows)  # fmt: skip
    if d.get("memory"):
        mem = [[p["scenes"], f"{p['ties']:,}", f"{p['unknowns']:,}", seconds(p.get("jaxgeo_s")),
                p.get("jaxgeo_steps", DASH),
                ms(p["jaxgeo_s"] / p["jaxgeo_steps"]) if p.get("jaxgeo_s") else DASH,
                mib(p["peak_bytes"])] for p in d["memory"]]  # fmt: skip
        out += ["", *table(["sub-scenes", "ties", "unknowns", "two-level call", "steps",
                            "per step", "peak memory (XLA)"], mem)]  # fmt: skip
    g = d.get("memory_scaling")
    if g:
        out += ["", f"Growth from the smallest to the largest strip over linear in the ties: "
                    f"time per step {num(g['time_per_step_growth_over_linear'])}x, peak memory "
                    f"{num(g['peak_growth_over_linear'])}x."]  # fmt: skip
    return out


def ortho(d: dict) -> list[str]:
    rows = [
        ["jaxgeo (COG written)", seconds(d["jaxgeo_s"]), "1x"],
        ["jaxgeo, first call (compilation)", seconds(d.get("jaxgeo_first_call_s")), DASH],
        ["GDAL warp, in memory", seconds(d["gdal_s"]),
         ratio(d.get("speed_ratio_gdal_over_jaxgeo"))],
        ["GDAL warp + COG written the same way", seconds(d.get("gdal_plus_cog_s")),
         ratio(d.get("speed_ratio_end_to_end"))],
    ]  # fmt: skip
    return [
        f"{d['scene']}; output {' x '.join(map(str, d['output_px']))} px.",
        "",
        *table(["", "time", "GDAL time over jaxgeo's"], rows),
        "",
        f"Mean difference of the sampled positions {num(d.get('mean_abs_diff_px'), 2)} px; "
        f"jaxgeo's grid error {num(d.get('grid_error_px'), 2)} px.",
    ]


def stereo_simulated(d: dict) -> list[str]:
    rows = []
    for r in d["rows"]:
        adj = r.get("adjustment") or {}
        check = adj.get("check_rms_m")
        check = " / ".join(num(x) for x in check) if check else DASH
        if "error" in r:
            rows.append([r["model"], r["gcps"] or DASH, f"error: {r['error']}", *[DASH] * 4])
            continue
        rows.append([r["model"], DASH if r["gcps"] is None else r["gcps"], num(r["rmse_m"]),
                     num(r["le90_m"]), num(r["mean_m"]), num(r["fill"]), check])  # fmt: skip
    paper = [[g, num(v["rmse_m"]), num(v["le90_m"])] for g, v in d.get("paper_table8", {}).items()]
    out = [
        f"{d['size_px']} px, GSD {d['gsd_m']} m, DSM cells {d['cell_m']} m, relief "
        f"{' - '.join(num(x) for x in d['relief_m'])} m, {d['n_ties_adjustment']} ties, "
        f"triangulation {d['triangulation']}; {seconds(d.get('total_s'))} in all.",
        "",
        *table(
            [
                "model",
                "GCPs",
                "height RMSE (m)",
                "LE90 (m)",
                "mean (m)",
                "fill",
                "check RMS E / N / U (m)",
            ],
            rows,
        ),  # fmt: skip
    ]
    if paper:
        out += ["", "The paper's table 8 (002_, real Cartosat-1, LPS, RPCs):", "",
                *table(["GCPs", "height RMSE (m)", "LE90 (m)"], paper)]  # fmt: skip
    return out


DH = ["median abs dh (m)", "p90 (m)", "p99 (m)", "mean dh (m)"]


def _dh(s: dict) -> list[str]:
    return [num(s.get(k)) for k in ("median_abs_dh_m", "p90_abs_dh_m", "p99_abs_dh_m", "mean_dh_m")]


def stereo_triplet(d: dict) -> list[str]:
    return table(
        ["triangulation", "registered", *DH, "share of s2p's cells filled", "wall time"],
        [[d["triangulation"], d["register"], *_dh(d), num(d["fill_of_s2p_cells"]),
          seconds(d.get("seconds"))]],
    )  # fmt: skip


def cars_triplet(d: dict) -> list[str]:
    rows = [["CARS - s2p", *_dh(d), num(d.get("fill_of_s2p_cells"))]]
    if "without_interpolated" in d:
        w = d["without_interpolated"]
        rows.append(["CARS - s2p, without CARS' interpolated cells", *_dh(w),
                     num(w.get("fill_of_s2p_cells"))])  # fmt: skip
    if "jaxgeo_vs_s2p" in d:
        j = d["jaxgeo_vs_s2p"]
        rows.append(["jaxgeo - s2p", *_dh(j), num(j.get("fill_of_s2p_cells"))])
    if "cars_vs_jaxgeo" in d:
        c = d["cars_vs_jaxgeo"]
        rows.append(["CARS - jaxgeo", *_dh(c), num(c.get("fill_of_jaxgeo_cells"))])
    return [
        f"CARS {d.get('cars_version', DASH)}, {d.get('nb_workers', DASH)} workers, "
        f"{seconds(d.get('seconds'))}; {d.get('resampling', '')}.",
        "",
        *table(["", *DH, "share of the reference's cells filled"], rows),
    ]


def strip_gross(d: dict) -> list[str]:
    rows = []
    for key, r in d.items():
        if not isinstance(r, dict) or "check_rms_plan_m" not in r:
            continue
        rms = r["check_rms_plan_m"]
        rows.append([key, num(rms.get("direct")), num(rms.get("level2")), seconds(r.get("solve_s")),
                     r.get("n_flagged", DASH), r.get("n_removed", DASH), num(r.get("recall")),
                     num(r.get("precision")), ", ".join(r.get("named", [])) or DASH])  # fmt: skip
    c = d.get("corrupted", {})
    return [
        f"Corrupted: {c.get('gcp_measurements', DASH)} GCP measurements, {c.get('ties', DASH)} "
        f"ties; options {json.dumps(d.get('args', {}))}.",
        "",
        *table(["run", "check RMS plan, vendor RPCs (m)", "after level 2 (m)", "solve (warm)",
                "flagged", "removed", "recall", "precision", "line offset named"], rows),
    ]  # fmt: skip


def dsm_scene(d: dict) -> list[str]:
    rows = []
    for name, m in d.get("jaxgeo", {}).items():
        acc, rep = m.get("accuracy", {}), m.get("report", {})
        rows.append(
            [
                name,
                str(rep.get("tiles", DASH)),
                seconds(m.get("wall_s")),
                seconds(m.get("cpu_s")),
                f"{num(m.get('peak_pss_gb'))} GB",
                num(m.get("scene_mpx_per_s")),
                num(acc.get("fill_of_truth")),
                f"{num(acc.get('median_abs_dh_m'))} m",
                f"{num(acc.get('nmad_m'))} m",
            ]
        )
    extra = d.get("extrapolation_40000px_16cores_h", {})
    one = d.get("jaxgeo", {}).get("workers1", {})
    size = re.search(r"--size (\d+)", d.get("scene", ""))
    by_cpu = None
    if one.get("cpu_s") and size:  # CPU seconds per Mpx of the scene, 16 cores kept busy
        by_cpu = one["cpu_s"] / (int(size.group(1)) ** 2 / 1e6) * 1600 / 16 / 3600
    return [
        f"{d['scene']}; warm-up (a {d.get('warmup_roi_px')} px ROI, untiled) "
        f"{seconds(d.get('warmup_s'))}.",
        "",
        *table(["", "tiles", "wall", "CPU", "peak PSS (tree)", "scene Mpx/s", "fill of truth",
                "median abs dh", "NMAD"], rows),
        "",
        f"1 -> 2 workers: {ratio(d.get('scaling_1_to_2_workers'))}; largest difference between "
        f"the worker counts {num(d.get('max_abs_difference_between_worker_counts_m'))} m. A "
        f"40 000 px pair on 16 cores: {num(extra.get('hours'))} h if every doubling of the "
        "workers gains what 1 -> 2 did here (a pessimistic bound: two cores shared with the "
        f"scheduler and the mosaic), {num(by_cpu)} h by one worker's CPU time with every core "
        "busy.",
    ]  # fmt: skip


def ortho_scene(d: dict) -> list[str]:
    rows = []
    for name, m in {**d.get("jaxgeo", {}), **d.get("gdal", {})}.items():
        label = f"jaxgeo, {name}" if name.startswith("workers") else name
        if name == "baseline":
            label = f"jaxgeo at {d.get('baseline')} (before), auto"
        rows.append([label, seconds(m.get("wall_s")), seconds(m.get("cpu_s")),
                     f"{num(m.get('peak_rss_gb'))} GB", f"{num(m.get('peak_pss_gb'))} GB",
                     num(m.get("mpx_per_s")), ratio(m.get("ratio_vs_gdal_gtiff")),
                     ratio(m.get("ratio_vs_gdal_cog"))])  # fmt: skip
    agree = d.get("agreement_vs_gdal", {})
    return [
        f"{d.get('scene')}; output {num(d.get('output_mpx'))} Mpx in {d.get('tiles')} tiles; "
        f"first run (compiling) {seconds(d.get('first_run_s'))}; GDAL with "
        f"{d.get('gdal_threads')} threads.",
        "",
        *table(["", "wall", "CPU", "peak RSS (tree)", "peak PSS (tree)", "output Mpx/s",
                "GDAL GTiff / jaxgeo", "GDAL COG / jaxgeo"], rows),
        "",
        f"Against GDAL: mean |difference| {num(agree.get('mean_abs_diff_dn'))} DN over the "
        f"{num(agree.get('both_valid'))} of the cells both fill.",
        *([] if "baseline" not in d else [
            "",
            f"Before ({d['baseline']}, same rounds): first run "
            f"{seconds(d.get('baseline_first_run_s'))}; its best warm wall time "
            f"{ratio(d.get('speedup_vs_baseline'))} this tree's, its CPU time "
            f"{ratio(d.get('cpu_speedup_vs_baseline'))}.",
        ]),
    ]  # fmt: skip


def cars_scene(d: dict) -> list[str]:
    rows = []
    for name in ("jaxgeo", "cars"):
        m = d.get(name, {})
        acc = m.get("accuracy", {})
        rows.append([name, seconds(m.get("wall_s")), seconds(m.get("cpu_s")),
                     f"{num(m.get('peak_pss_gb'))} GB", num(acc.get("fill_of_truth")),
                     f"{num(acc.get('median_abs_dh_m'))} m", f"{num(acc.get('nmad_m'))} m",
                     f"{num(acc.get('p95_abs_dh_m'))} m"])  # fmt: skip
    return [
        f"{d.get('scene')}; {d.get('workers')} workers each.",
        "",
        *table(["", "wall", "CPU", "peak PSS (tree)", "fill of truth", "median abs dh", "NMAD",
                "p95 abs dh"], rows),
        "",
        f"CARS's wall time over jaxgeo's: {ratio(d.get('cars_over_jaxgeo_wall'))}.",
    ]  # fmt: skip


DEVICE_CASES = (
    "device",
    "device_transposing",
    "device_columns",
    "device_interleaved",
    "device_columns_div",
    "copy",
    "numpy",
    "numpy_host_model",
    "numpy_whole",
    "numpy_pinned",
    "localize_device",
    "localize_numpy",
)


def device(d: dict) -> list[str]:
    """One row per case, one column per size: M points/s, the fraction of the copy bound."""
    rows_in = d["results"]
    head = ["case", *(f"{r['points']:.0e} points: M pts/s (of copy, of nominal)" for r in rows_in)]
    rows = []
    for case in DEVICE_CASES:
        cells = []
        for r in rows_in:
            rate = r.get(f"{case}_points_per_s")
            of_copy, of_nominal = (r.get(f"{case}_fraction_of_{k}") for k in ("copy", "nominal"))
            fractions = (f" ({of_copy:.0%}, {of_nominal:.0%})" if of_copy is not None
                         and of_nominal is not None else "")  # fmt: skip
            cells.append(mpts(rate) + (fractions if rate is not None else ""))
        if any(c != DASH for c in cells):
            rows.append([f"`{case}`", *cells])
    nominal = d.get("bandwidth_nominal_bytes_per_s")
    return [
        *table(head, rows),
        "",
        f"Backend {d.get('backend', DASH)}; nominal bound {num(nominal)} B/s at 40 B a point. "
        "Localisation rows: a tenth of the points.",
    ]


def generic(d: dict) -> list[str]:
    """Any study: its numbers, strings and booleans, those of nested objects as ``a.b``."""

    def flat(obj, prefix=""):
        for k, v in obj.items():
            if isinstance(v, dict):
                yield from flat(v, f"{prefix}{k}.")
            elif isinstance(v, int | float | str | bool) or v is None:
                yield f"{prefix}{k}", v

    rows = [[f"`{k}`", num(v)] for k, v in flat({k: v for k, v in d.items() if k != "machine"})]
    return table(["key", "value"], rows)


SUMMARIES: dict[str, Callable[[dict], list[str]]] = {
    "projection": points,
    "device": device,
    "localization": points,
    "localize_dem": localize_dem,
    "batch": batch,
    "cli_times": cli_times,
    "adjust_scale": adjust_scale,
    "strip": strip,
    "ortho": ortho,
    "stereo_simulated": stereo_simulated,
    "stereo_triplet": stereo_triplet,
    "cars_triplet": cars_triplet,
    "strip_gross": strip_gross,
    "dsm_scene": dsm_scene,
    "cars_scene": cars_scene,
    "ortho_scene": ortho_scene,
}
