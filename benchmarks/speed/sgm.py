"""The dense matcher alone: jaxgeo's census SGM in JAX against OpenCV's StereoSGBM (3-way, the
``opencv`` matcher) on one tile, in Mpx/s, same run.

    python -m benchmarks.speed.sgm [--rows 512] [--cols 1024] [--disparities 64 128]
        [--paths 8] [--repeats 3]

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
"""

from __future__ import annotations

import argparse
import functools
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


def main() -> None:
    import jax

    from jaxgeo.stereo import SGMSettings, sgm_disparity

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=512)
    parser.add_argument("--cols", type=int, default=1024)
    parser.add_argument("--disparities", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--paths", type=int, default=8, choices=(4, 8))
    parser.add_argument("--repeats", type=int, default=3)
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
    summary = {}  # the headline numbers flat, one key per disparity count (the README's table)
    for case in cases:
        for key in ("jax_mpx_per_s", "opencv_mpx_per_s", "opencv_over_jax_time", "jax_first_s"):
            summary[f"{key}_d{case['disparities']}"] = round(case[key], 4)
    emit(
        {
            "benchmark": "sgm_matcher",
            "tile": [args.rows, args.cols],
            "paths": args.paths,
            "device": str(jax.devices()[0]),
            **summary,
            "cases": cases,
        }
    )


if __name__ == "__main__":
    main()
