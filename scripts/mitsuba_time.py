#!/usr/bin/env python3
"""Times Mitsuba 3 on a scene that `cargo bench --bench tracer` wrote, for the bench's
`glimpse / mitsuba` ratio measured in one run.

The bench writes a folder with `scene.json` (image size, spp, max_bounces, camera, and per
object its OBJ file and material: diffuse albedo or emitted radiance) and one OBJ per
object: the same triangles, materials and camera as the Glimpse render.

Protocol (stdin/stdout, one line each), so that the bench can interleave its renders with
Mitsuba's: the script loads the scene, renders it once untimed (Dr.Jit's LLVM kernel
compilation and the scene load are not rendering time) and prints `ready VARIANT`; then
for every line `render` on stdin it renders once and prints `seconds MEAN` (the wall time
of mi.render plus the read-back that forces evaluation, and the image's mean). EOF ends it.

Equivalences (Mitsuba 3 path integrator, src/render/integrators/path.cpp): Glimpse's
`max_bounces = b` counts scattering events; Mitsuba's `max_depth` counts path vertices
including the emitter, so `max_depth = b + 1`. Russian roulette: Glimpse starts it once
3 scattering events are done (integrator.rs RR_START); Mitsuba's `depth` counts the
same events when it tests `depth >= rr_depth`, so `rr_depth = 3`. Glimpse's diffuse
surfaces shade both sides: Mitsuba's `diffuse` is wrapped in `twosided`. Emitters are
one-sided (`area`), as in the scene. Sampler: Mitsuba's `independent`.

Usage: DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 \
  python3 scripts/mitsuba_time.py SCENE_DIR [--variant llvm_ad_rgb] [--runs N]
Without a stdin protocol partner, `--runs N` renders N times and prints the median.
"""

import argparse
import glob
import json
import os
import statistics
import sys
import time

# Dr.Jit's LLVM backend needs libLLVM >= 18 (scripts/mitsuba.sh installs 19).
if "DRJIT_LIBLLVM_PATH" not in os.environ:
    newest = sorted(glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM.so.19*"))
    if newest:
        os.environ["DRJIT_LIBLLVM_PATH"] = newest[-1]


def scene_dict(mi, folder: str) -> dict:
    with open(os.path.join(folder, "scene.json")) as f:
        doc = json.load(f)
    cam = doc["camera"]
    d = {
        "type": "scene",
        "integrator": {
            "type": "path",
            "max_depth": doc["max_bounces"] + 1,
            "rr_depth": 3,
        },
        "sensor": {
            "type": "perspective",
            "fov": cam["fov_y_deg"],
            "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=cam["position"], target=cam["look_at"], up=cam["up"]
            ),
            "film": {
                "type": "hdrfilm",
                "width": doc["width"],
                "height": doc["height"],
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
            },
            "sampler": {"type": "independent", "sample_count": doc["spp"]},
        },
    }
    for i, obj in enumerate(doc["objects"]):
        shape = {"type": "obj", "filename": os.path.join(folder, obj["obj"]), "face_normals": True}
        if "radiance" in obj:
            shape["bsdf"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0, 0, 0]}}
            shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": obj["radiance"]}}
        else:
            shape["bsdf"] = {
                "type": "twosided",
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": obj["albedo"]}},
            }
        d[f"object{i}"] = shape
    return d


def render_once(mi, scene, spp: int, seed: int):
    t0 = time.perf_counter()
    img = mi.render(scene, spp=spp, seed=seed)
    mean = float(mi.TensorXf(img).numpy().mean())  # forces evaluation in the JIT variants
    return time.perf_counter() - t0, mean


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("scene_dir")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--runs", type=int, default=0, help="render N times, print the median (no protocol)")
    a = ap.parse_args()
    import mitsuba as mi

    mi.set_variant(a.variant)
    scene = mi.load_dict(scene_dict(mi, a.scene_dir))
    spp = json.load(open(os.path.join(a.scene_dir, "scene.json")))["spp"]
    render_once(mi, scene, spp, 0)  # warm-up: JIT compilation and scene upload
    if a.runs > 0:
        times = [render_once(mi, scene, spp, i + 1)[0] for i in range(a.runs)]
        print(f"{a.variant}: median {statistics.median(times):.2f} s (runs {times})")
        return 0
    print(f"ready {a.variant}", flush=True)
    seed = 1
    for line in sys.stdin:
        if line.strip() != "render":
            continue
        secs, mean = render_once(mi, scene, spp, seed)
        seed += 1
        print(f"seconds {secs:.6f} {mean:.6f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
