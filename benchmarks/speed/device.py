"""RPC projection and localisation on the default jax device (a GPU when there is one): arrays on
the device, numpy in and out, and the memory bound, same run.

    python -m benchmarks.speed.device [--sizes 1e6 1e7 1e8] [--repeats 10] [--hlo FILE]

Run it twice on one machine for a same-machine baseline: on the GPU, then with
``JAX_PLATFORMS=cpu``. Cases, each the best of ``--repeats`` calls after a warm-up, points/s:

- ``device``: ``rpc.project(ground)`` with ``ground`` a jax array on the device (the
  device-array API: a jax array in, a jax array out, no copy to the host);
- ``device_columns``: the kernel on separate ``lon, lat, h`` device arrays, ``x, y`` out (no
  interleaved ``(n, 3)`` / ``(n, 2)`` layout);
- ``device_interleaved``: the kernel reading the ``(n, 3)`` columns in place and writing
  ``(n, 2)`` directly (no transposing copies in and out, which the CPU kernel makes: what
  ``device`` ran on a GPU before ``_project_body_direct``);
- ``device_transposing``: the CPU's kernel (transposing copies in and out) on the device;
- ``device_columns_div``: ``device_columns`` with the ground normalised by a float64 division
  per point (the kernel before issue 29: XLA's GPU fusion then splits it in two);
- ``numpy``: ``rpc.project(numpy)``, numpy out (as README writes it; every copy included; on
  a GPU machine computed on the host's CPU);
- ``numpy_host_model``: ``numpy`` with the model's arrays put on the host's CPU device first
  (on a GPU machine ``numpy`` computes there with a model whose arrays are on the GPU: the
  difference is what moving them costs a call; on a CPU the same as ``numpy``);
- ``numpy_whole``: the same data moved in one ``device_put``, one call, one copy back;
- ``numpy_pinned``: through pinned host memory (``memory_kind="pinned_host"``) where the
  backend has it;
- ``copy``: a kernel that reads the ``(n, 3)`` input and writes an ``(n, 2)`` output with one
  multiply each: the same memory traffic as a projection (40 B a point), its measured bound;
- ``localize_device``: ``rpc.localize(xy, h)`` on device arrays, ``localize_numpy`` with numpy
  in and out (a tenth of the points).

``fraction_of_copy`` = a case's points/s over ``copy``'s; ``fraction_of_nominal`` over
``--bandwidth`` (bytes/s, the card's data sheet: 3.35e12 for an H100 SXM) / 40 B. ``--hlo``
writes the optimised program of each projection variant (its fusions: one kernel or several).
The RPC: the real Pleiades scene of ../shared/data/real, uniform points in its validity cube.
"""

from __future__ import annotations

import argparse
import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import best_of, emit
from benchmarks.speed.localize_traced import pleiades_rpc
from jaxgeo.models import _rpc_eval
from jaxgeo.models._host import host_device

BYTES_PER_POINT = 40
"""A projection reads lon, lat, h and writes x, y: five float64."""


def _columns(rpc, lon, lat, h):
    return _rpc_eval.project_lph(rpc, lon, lat, h)


def _interleaved(rpc, ground):
    x, y = _rpc_eval.project_lph(rpc, ground[:, 0], ground[:, 1], ground[:, 2])
    return jnp.stack([x, y], axis=-1)


def _columns_div(rpc, lon, lat, h):
    go, gs = rpc.ground_offset, rpc.ground_scale
    lon = lon - 360.0 * jnp.ceil((lon - go[0] - 180.0) / 360.0)
    ln, pn, hn = (lon - go[0]) / gs[0], (lat - go[1]) / gs[1], (h - go[2]) / gs[2]
    r = _rpc_eval.rational
    x = r(rpc.num[0], ln, pn, hn) / r(rpc.den[0], ln, pn, hn)
    y = r(rpc.num[1], ln, pn, hn) / r(rpc.den[1], ln, pn, hn)
    return rpc.image_offset[0] + rpc.image_scale[0] * x, rpc.image_offset[1] + rpc.image_scale[
        1
    ] * y


def _copy(ground):
    return ground[:, :2] * 1.000001


def _pinned(device):
    """A sharding of pinned host memory on ``device``, or ``None`` where there is none."""
    try:
        sharding = jax.sharding.SingleDeviceSharding(device, memory_kind="pinned_host")
        jax.device_put(np.zeros(4), sharding).block_until_ready()
        return sharding
    except Exception:  # noqa: BLE001  (a backend without that memory kind)
        return None


def measure(rpc, n: int, repeats: int, hlo: dict) -> dict:
    rng = np.random.default_rng(0)
    go, gs = np.asarray(rpc.ground_offset), np.asarray(rpc.ground_scale)
    ground = go + rng.uniform(-0.9, 0.9, (n, 3)) * gs
    device = jax.devices()[0]
    g_dev = jax.device_put(ground, device)
    cols = [jax.device_put(np.ascontiguousarray(ground[:, k]), device) for k in range(3)]
    columns = jax.jit(_columns)
    columns_div = jax.jit(_columns_div)
    interleaved = jax.jit(_interleaved)
    copy = jax.jit(_copy)
    on_cpu = device.platform == "cpu"
    kernel = _rpc_eval._project_kernel if on_cpu else _rpc_eval._project_kernel_direct
    flat = _rpc_eval._flat(rpc)
    rpc_host = jax.device_put(rpc, host_device())
    transposing = _rpc_eval._project_kernel
    cases = {
        "device": lambda: rpc.project(g_dev),
        "device_transposing": lambda: transposing(*flat, g_dev),
        "device_columns": lambda: columns(rpc, *cols),
        "device_interleaved": lambda: interleaved(rpc, g_dev),
        "device_columns_div": lambda: columns_div(rpc, *cols),
        "copy": lambda: copy(g_dev),
        "numpy": lambda: rpc.project(ground),
        "numpy_host_model": lambda: rpc_host.project(ground),
        "numpy_whole": lambda: np.asarray(interleaved(rpc, jax.device_put(ground, device))),
    }
    pinned = _pinned(device)
    if pinned is not None:
        to_host = jax.jit(_interleaved, out_shardings=pinned)
        cases["numpy_pinned"] = lambda: np.asarray(to_host(rpc, jax.device_put(ground, pinned)))
    if n <= 10_000_000:
        xy = np.asarray(rpc.project(ground[: n // 10]))
        xy_dev, h_dev = jax.device_put(xy, device), jax.device_put(ground[: n // 10, 2], device)
        cases["localize_device"] = lambda: rpc.localize(xy_dev, h_dev)
        cases["localize_numpy"] = lambda: rpc.localize(xy, ground[: n // 10, 2])
    out: dict = {"points": n}
    times = {}
    for name, fn in cases.items():
        try:
            timing = best_of(fn, repeats)
        except Exception as e:  # noqa: BLE001  (reported, the other cases still measured)
            out[f"{name}_error"] = f"{type(e).__name__}: {e}"[:300]
            continue
        points = n // 10 if name.startswith("localize") else n
        times[name] = timing.best_s
        out[f"{name}_points_per_s"] = points / timing.best_s
        out[f"{name}_first_s"] = timing.first_s
    if "copy" in times:
        for name, t in times.items():
            if name != "copy" and not name.startswith("localize"):
                out[f"{name}_fraction_of_copy"] = times["copy"] / t
    ref = np.asarray(rpc.project(g_dev))
    out["max_diff_interleaved_px"] = float(np.abs(np.asarray(interleaved(rpc, g_dev)) - ref).max())
    out["max_diff_numpy_px"] = float(np.abs(rpc.project(ground) - ref).max())
    out["max_diff_division_px"] = float(
        max(np.abs(np.asarray(a) - ref[:, k]).max() for k, a in enumerate(columns_div(rpc, *cols)))
    )
    if not hlo:
        for name, (fn, args) in {
            "device": (kernel, (*flat, g_dev)),
            "device_transposing": (transposing, (*flat, g_dev)),
            "device_columns": (columns, (rpc, *cols)),
            "device_interleaved": (interleaved, (rpc, g_dev)),
            "device_columns_div": (columns_div, (rpc, *cols)),
        }.items():
            text = fn.lower(*args).compile().as_text()
            hlo[name] = text
            out[f"{name}_kernels"] = text.count(" fusion(") + text.count("custom-call(")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e6, 1e7, 1e8])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--bandwidth", type=float, default=3.35e12, help="bytes/s, nominal")
    parser.add_argument("--hlo", type=pathlib.Path, help="write the optimised programs here")
    args = parser.parse_args()
    rpc = pleiades_rpc()
    hlo: dict[str, str] = {}
    results = []
    for size in args.sizes:
        row = measure(rpc, int(size), args.repeats, hlo)
        for key in [k for k in row if k.endswith("_points_per_s")]:
            if not key.startswith("localize"):
                frac = row[key] * BYTES_PER_POINT / args.bandwidth
                row[key.replace("_points_per_s", "_fraction_of_nominal")] = frac
        results.append(row)
    if args.hlo:
        args.hlo.write_text("".join(f"=== {k}\n{v}\n" for k, v in hlo.items()))
    emit(
        {
            "benchmark": "device",
            "backend": jax.default_backend(),
            "bandwidth_nominal_bytes_per_s": args.bandwidth,
            "results": results,
        }
    )


if __name__ == "__main__":
    main()
