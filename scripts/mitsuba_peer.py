#!/usr/bin/env python3
"""Mitsuba 3's path tracer on its built-in Cornell box, for `glimpse bench`'s peer column.

Renders a converged image (--converged-spp) and, at equal time, as many samples per pixel
as fit in --seconds (measured from a 1-spp pass), at --size x --size, path depth 6.
Prints one JSON object: variant, spp, ms, test_exr, converged_exr.
"""
import argparse, glob, json, os, time

# Dr.Jit's LLVM backend aborts on Debian 12's LLVM 15/16 ("fminimum"); point it at a newer
# libLLVM when one is installed (apt-get install libllvm19), else the scalar variant is used.
if "DRJIT_LIBLLVM_PATH" not in os.environ:
    newest = sorted(glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM.so.19*"))
    if newest:
        os.environ["DRJIT_LIBLLVM_PATH"] = newest[-1]

import mitsuba as mi

ap = argparse.ArgumentParser()
ap.add_argument("--size", type=int, default=512)
ap.add_argument("--seconds", type=float, required=True)
ap.add_argument("--converged-spp", type=int, default=1024)
ap.add_argument("--out", required=True)
a = ap.parse_args()

variant = "scalar_rgb"
if "DRJIT_LIBLLVM_PATH" in os.environ and "llvm_ad_rgb" in mi.variants():
    variant = "llvm_ad_rgb"
mi.set_variant(variant)

def scene_with(spp):
    d = mi.cornell_box()
    d["sensor"]["film"]["width"] = a.size
    d["sensor"]["film"]["height"] = a.size
    d["sensor"]["sampler"]["sample_count"] = spp
    d["integrator"] = {"type": "path", "max_depth": 7}  # Mitsuba counts the emitter vertex: 7 = our 6 bounces
    return mi.load_dict(d)

def render(spp, seed):
    s = scene_with(spp)
    t = time.perf_counter()
    img = mi.render(s, spp=spp, seed=seed)
    mi.Bitmap(img)  # forces evaluation in the JIT variants
    return img, (time.perf_counter() - t) * 1e3

render(1, 0)  # warm-up: JIT compilation is not rendering time
_, one = render(1, 1)
spp = max(1, int(a.seconds * 1e3 / max(one, 1e-3)))
img, ms = render(spp, 2)
# Refine once: per-spp cost is not linear at low counts (fixed overhead per launch).
if ms > 1.3 * a.seconds * 1e3 and spp > 1:
    spp = max(1, int(spp * a.seconds * 1e3 / ms))
    img, ms = render(spp, 3)
test = os.path.join(a.out, "mitsuba-test.exr")
mi.util.write_bitmap(test, img)
ref, _ = render(a.converged_spp, 4)
conv = os.path.join(a.out, "mitsuba-converged.exr")
mi.util.write_bitmap(conv, ref)
print(json.dumps({"variant": variant, "spp": spp, "ms": ms, "test_exr": test, "converged_exr": conv}))
