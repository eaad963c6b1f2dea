#!/usr/bin/env python3
"""Times Mitsuba 3's built-in Cornell box at 512x512, 64 spp, on this machine, for a
side-by-side comparison with `cargo bench --bench tracer`.

Depth: Glimpse's `max_bounces = 6` counts scattering events (pbrt's maxdepth); Mitsuba's
`max_depth` counts path vertices including the emitter, so the equivalent is
`max_depth = 7`. Both values are timed. Russian roulette: Mitsuba's default (`rr_depth`
5); Glimpse starts it after 3 bounces.

Usage: pip install mitsuba numpy && python3 scripts/mitsuba_cornell.py [--runs 3]
The llvm variant needs libLLVM >= 18 (Dr.Jit 1.x emits `fminimum`, which LLVM 15/16 cannot
select and abort on): apt-get install libllvm19, then run with
DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1. A variant that fails to load
is reported as unavailable; an LLVM abort kills the process, so run the variants separately
(--variants scalar_rgb, then --variants llvm_ad_rgb) if unsure.
Each timing renders once untimed first (JIT compilation, scene load), then reports the
median of --runs renders.
"""

import argparse
import statistics
import sys
import time


def time_variant(variant: str, max_depth: int, runs: int, size: int, spp: int):
    import mitsuba as mi

    mi.set_variant(variant)
    scene_dict = mi.cornell_box()
    scene_dict["sensor"]["film"]["width"] = size
    scene_dict["sensor"]["film"]["height"] = size
    scene_dict["sensor"]["sampler"]["sample_count"] = spp
    scene_dict["integrator"] = {"type": "path", "max_depth": max_depth}
    scene = mi.load_dict(scene_dict)
    img = mi.render(scene, spp=spp)  # warm-up (JIT for llvm)
    _ = float(mi.TensorXf(img).numpy().mean())
    times = []
    for i in range(runs):
        t0 = time.perf_counter()
        img = mi.render(scene, spp=spp, seed=i + 1)
        mean = float(mi.TensorXf(img).numpy().mean())  # forces evaluation
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times, mean


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--variants", default="scalar_rgb,llvm_ad_rgb")
    ap.add_argument("--depths", default="7,6")
    args = ap.parse_args()
    try:
        import mitsuba as mi
    except ImportError:
        print("mitsuba is not installed: pip install mitsuba", file=sys.stderr)
        return 1
    print(f"mitsuba {mi.__version__}, cornell box {args.size}x{args.size}, {args.spp} spp")
    for variant in args.variants.split(","):
        for depth in (int(d) for d in args.depths.split(",")):
            try:
                med, times, mean = time_variant(variant, depth, args.runs, args.size, args.spp)
            except Exception as e:  # a missing LLVM must not hide the other numbers
                print(f"{variant} max_depth={depth}: unavailable ({e})")
                break
            runs = ", ".join(f"{t:.2f}" for t in times)
            print(f"{variant} max_depth={depth}: median {med:.2f} s (runs {runs}), mean {mean:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
