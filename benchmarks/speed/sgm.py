"""The dense matcher alone: jaxgeo's census SGM in JAX against OpenCV's StereoSGBM (3-way, the
``opencv`` matcher) on one tile, in Mpx/s, same run.

    python -m benchmarks.speed.sgm [--rows 512] [--cols 1024] [--disparities 64 128]
        [--paths 8] [--repeats 3] [--no-memory]

The tile: a rectified pair made of a blurred noise texture (the rendered scenes' kind) and its
band-limited shift of -``D/3`` px (so that matches exist over the whole range), as uint8. Each
matcher runs ``sgm_disparity`` with the default :class:`jaxgeo.stereo.SGMSettings` (uniqueness,
left-right check and speckle filter included, as in a DSM) over ``D`` disparities. The JAX
matcher runs on JAX's default device: the images are put there first (``jax.device_put``) and
every timed call waits on its result (``block_until_ready``; the disparities come back to the
host as numpy, as in the DSM chain); its first call (tracing, and XLA's compilation unless
jaxgeo's persistent compilation cache holds the program) is reported apart as ``jax_first_s``,
not in the rate. Prints one JSON object: per ``D``, Mpx/s of each
matcher (tile pixels / best time) and their ratio, the share of pixels within 1 px of each
other, each matcher's fill and median error against the known shift. The same file runs on a
GPU unchanged.

Memory (unless ``--no-memory``): per ``D``, each in a fresh process (an allocator keeps what an
earlier call freed), the peak memory of one JAX band beyond the process's before it -- resident
set on a CPU (sampled every 2 ms), the device's ``peak_bytes_in_use`` on a GPU -- against the
model the matcher sizes its chunks with (``band_bytes``), once as one band and once with a budget
of a quarter of it (``memory_mb``: matched in chunks of rows), with that run's rate.
"""

from __future__ import annotations

import argparse
import functools
import json
import subprocess
import sys
import threading
import time

import numpy as np

from benchmarks.harness import emit


def tile(rows: int, cols: int, shift_px: float, seed: int = 0):
    """Left and right uint8 images (``right(x + shift_px) = left(x)``)."""
    import cv2

    noise = np.random.default_rng(seed).normal(size=(rows, cols)).astype(np.float32)
    left = cv2.GaussianBlur(noise, (0, 0), 1.2)
    k = np.fft.fftfreq(cols)
    spectrum = np.fft.fft(left, axis=1) * np.exp(-2j * np.pi * k * shift_px)
    right = np.real(np.fft.ifft(spectrum, axis=1)).astype(np.float32)
    lo, hi = float(min(left.min(), right.min())), float(max(left.max(), right.max()))

    def to8(a):
        return np.clip(np.rint(255 * (a - lo) / (hi - lo)), 0, 255).astype(np.uint8)

    return to8(left), to8(right)


def best(fn, repeats):
    """``(best seconds, first seconds, output)`` of ``repeats`` calls after one warm-up."""
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), first, out


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096


def band_peak(rows: int, cols: int, n_disp: int, memory_mb: float | None) -> dict:
    """Peak memory (bytes) of one JAX band beyond the process's before it (compiled first), the
    seconds of that band, and the model's ``band_bytes``; in this process."""
    import jax

    from jaxgeo.stereo import SGMSettings, sgm_disparity
    from jaxgeo.stereo._sgm import band_bytes

    left8, right8 = tile(rows, cols, -n_disp / 3.0)
    drange = (float(-n_disp + 8), 7.0)
    run = functools.partial(sgm_disparity, left8, right8, *drange,
                            SGMSettings(matcher="jax", memory_mb=memory_mb))  # fmt: skip
    device = jax.devices()[0]
    stats = device.memory_stats() or {}  # (an accelerator's peak counts from here: first run)
    run()  # compiled, and the host allocator's pools made
    base, peak, done = _rss_bytes(), [0], threading.Event()

    def sample():
        while not done.is_set():
            peak[0] = max(peak[0], _rss_bytes())
            time.sleep(0.002)

    sampler = threading.Thread(target=sample)
    sampler.start()
    t0 = time.perf_counter()
    run()
    seconds = time.perf_counter() - t0
    done.set()
    sampler.join()
    if stats.get("peak_bytes_in_use") is not None:  # an accelerator: its own count
        used = (device.memory_stats() or {}).get("peak_bytes_in_use", 0) - stats.get(
            "bytes_in_use", 0
        )
        kind = "device peak_bytes_in_use"
    else:
        used, kind = max(peak[0] - base, 0), "host resident set"
    return {"disparities": n_disp, "memory_mb": memory_mb, "peak_bytes": int(used),
            "measured": kind, "model_bytes": band_bytes(rows, cols, n_disp), "seconds": seconds,
            "mpx_per_s": rows * cols / 1e6 / seconds}  # fmt: skip


def _band_peak_in_a_new_process(rows, cols, n_disp, memory_mb):
    code = ("import json, sys; from benchmarks.speed.sgm import band_peak; "
            f"print(json.dumps(band_peak({rows}, {cols}, {n_disp}, {memory_mb!r})))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def memory_summary(memory: list[dict]) -> dict:
    """The memory runs' headline numbers flat (MB): per ``D`` the model, the peak of one band,
    the peak in chunks and the budget they were given."""
    out = {}
    for m in memory:
        d, mb = m["disparities"], 2.0**20
        if m["memory_mb"] is None:
            out[f"band_model_mb_d{d}"] = round(m["model_bytes"] / mb, 1)
            out[f"band_peak_mb_d{d}"] = round(m["peak_bytes"] / mb, 1)
        else:
            out[f"chunks_budget_mb_d{d}"] = round(m["memory_mb"], 1)
            out[f"chunks_peak_mb_d{d}"] = round(m["peak_bytes"] / mb, 1)
    return out


def main() -> None:
    import jax

    from jaxgeo.stereo import SGMSettings, sgm_disparity

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=512)
    parser.add_argument("--cols", type=int, default=1024)
    parser.add_argument("--disparities", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--paths", type=int, default=8, choices=(4, 8))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-memory", action="store_true", help="skip the memory runs")
    args = parser.parse_args()
    mpx = args.rows * args.cols / 1e6
    cases = []
    for n_disp in args.disparities:
        shift = -n_disp / 3.0
        left8, right8 = tile(args.rows, args.cols, shift)
        drange = (float(-n_disp + 8), 7.0)  # n_disp whole disparities around the shift
        opencv = functools.partial(sgm_disparity, left8, right8, *drange,
                                   SGMSettings(matcher="opencv"))  # fmt: skip
        on_device = jax.device_put(left8), jax.device_put(right8)
        census = functools.partial(sgm_disparity, *on_device, *drange,
                                   SGMSettings(matcher="jax", paths=args.paths))  # fmt: skip
        cv_s, _, d_cv = best(opencv, args.repeats)
        jax_s, first_s, d_jax = best(census, args.repeats)
        core = (slice(8, -8), slice(n_disp, -n_disp))
        both = np.isfinite(d_cv[core]) & np.isfinite(d_jax[core])
        cases.append(
            {
                "disparities": n_disp,
                "shift_px": shift,
                "jax_mpx_per_s": mpx / jax_s,
                "opencv_mpx_per_s": mpx / cv_s,
                "jax_s": jax_s,
                "opencv_s": cv_s,
                "jax_first_s": first_s,
                "opencv_over_jax_time": cv_s / jax_s,
                "within_1px": float(np.mean(np.abs(d_cv - d_jax)[core][both] <= 1.0)),
                "fill_jax": float(np.isfinite(d_jax[core]).mean()),
                "fill_opencv": float(np.isfinite(d_cv[core]).mean()),
                "median_abs_error_jax_px": float(np.nanmedian(np.abs(d_jax[core] - shift))),
                "median_abs_error_opencv_px": float(np.nanmedian(np.abs(d_cv[core] - shift))),
            }
        )
    memory = []
    if not args.no_memory:
        from jaxgeo.stereo._sgm import band_bytes

        for n_disp in args.disparities:
            quarter = band_bytes(args.rows, args.cols, n_disp) / 4 / 2**20
            for memory_mb in (None, quarter):
                memory.append(_band_peak_in_a_new_process(args.rows, args.cols, n_disp, memory_mb))
    summary = {}  # the headline numbers flat, one key per disparity count (the README's table)
    for case in cases:
        for key in ("jax_mpx_per_s", "opencv_mpx_per_s", "opencv_over_jax_time", "jax_first_s"):
            summary[f"{key}_d{case['disparities']}"] = round(case[key], 4)
    summary |= memory_summary(memory)
    emit(
        {
            "benchmark": "sgm_matcher",
            "tile": [args.rows, args.cols],
            "paths": args.paths,
            "device": str(jax.devices()[0]),
            **summary,
            "cases": cases,
            "memory": memory,
        }
    )


if __name__ == "__main__":
    main()
