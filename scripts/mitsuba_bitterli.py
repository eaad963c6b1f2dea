#!/usr/bin/env python3
"""Renders Glimpse's `scenes/cornell-box.json` (Bitterli's Cornell box: same camera,
albedos, light) with Mitsuba 3 and compares its mean linear RGB with Tungsten's converged
reference, as the tracer's agreement target asks ("Mitsuba 3 on the same box at 64 spp lands within 1 % of
it"). This checks the peer, not Glimpse: Glimpse's own check is
tests/tracer_analytic.rs; the script also renders Glimpse's image of the same scene with
the same settings when a built `glimpse` binary is given, so the three means sit side by
side.

The scene is translated from Glimpse's own document, not retyped: every `mesh` object
becomes a PLY file, the `quad` light a two-triangle emitter facing edge_u × edge_v (the
side Glimpse's quads emit from). Depth: Tungsten traced up to 64 bounces; Mitsuba's
`max_depth` counts path vertices including the emitter, so 65. Film: box filter, as both
other renderers.

Usage: pip install mitsuba numpy &&
  python3 scripts/mitsuba_bitterli.py [--spp 64] [--size 256] [--variant scalar_rgb]
      [--glimpse target/release/glimpse]
"""

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
TUNGSTEN = ROOT.parent / "shared/scenes-public/cornell-box-bitterli/TungstenRender.exr"
TUNGSTEN_MEAN = (0.1963, 0.1275, 0.0361)  # measured from TungstenRender.exr


def write_ply(path, positions, faces):
    with open(path, "w") as f:
        f.write("ply\nformat ascii 1.0\n")
        f.write(f"element vertex {len(positions)}\nproperty float x\nproperty float y\nproperty float z\n")
        f.write(f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
        for p in positions:
            f.write(f"{p[0]} {p[1]} {p[2]}\n")
        for t in faces:
            f.write(f"3 {t[0]} {t[1]} {t[2]}\n")


def scene_dict(doc, tmp, size, spp):
    import mitsuba as mi

    cam = doc["camera"]
    out = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 65},
        "sensor": {
            "type": "perspective",
            "fov": cam["fov_y"],
            "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=cam["position"], target=cam["look_at"], up=cam.get("up", [0, 1, 0])
            ),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {
                "type": "hdrfilm",
                "width": size,
                "height": size,
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
            },
        },
    }
    for k, o in enumerate(doc["objects"]):
        mat = doc["materials"][o["material"]]
        if o["type"] == "mesh":
            if "transform" in o:
                sys.exit(f"object {k}: transforms are not translated by this script")
            positions, faces = o["positions"], o["indices"]
        elif o["type"] == "quad":
            c, u, v = o["corner"], o["edge_u"], o["edge_v"]
            add = lambda a, b: [a[i] + b[i] for i in range(3)]
            positions = [c, add(c, u), add(add(c, u), v), add(c, v)]
            faces = [[0, 1, 2], [0, 2, 3]]  # normal u × v, as Glimpse's quads
        else:
            sys.exit(f"object {k}: type {o['type']} is not translated by this script")
        ply = os.path.join(tmp, f"o{k}.ply")
        write_ply(ply, positions, faces)
        shape = {"type": "ply", "filename": ply, "face_normals": True}
        if mat["type"] == "diffuse":
            # Mitsuba's diffuse BSDF is one-sided (black from behind); Glimpse's and
            # Tungsten's are two-sided, and the box meshes do not all face inwards.
            shape["bsdf"] = {
                "type": "twosided",
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": mat["albedo"]}},
            }
        elif mat["type"] == "emissive":
            shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": mat["radiance"]}}
            shape["bsdf"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0, 0, 0]}}
        else:
            sys.exit(f"material {o['material']}: type {mat['type']} is not translated")
        out[f"object{k}"] = shape
    return out


def mean_rgb(path_or_array):
    import mitsuba as mi
    import numpy as np

    if isinstance(path_or_array, (str, pathlib.Path)):
        a = np.array(mi.Bitmap(str(path_or_array)).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32))
    else:
        a = np.array(path_or_array)
    return tuple(float(a[..., c].mean()) for c in range(3))


def report(name, m, ref):
    diffs = ", ".join(f"{100 * (m[c] - ref[c]) / ref[c]:+.2f} %" for c in range(3))
    print(f"{name:28s} mean ({m[0]:.4f}, {m[1]:.4f}, {m[2]:.4f})  vs Tungsten: {diffs}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--variant", default="scalar_rgb")
    ap.add_argument("--glimpse", help="a built glimpse binary: also render Glimpse's image")
    a = ap.parse_args()
    import mitsuba as mi

    mi.set_variant(a.variant)
    doc = json.loads((ROOT / "scenes/cornell-box.json").read_text())
    ref = mean_rgb(TUNGSTEN) if TUNGSTEN.exists() else TUNGSTEN_MEAN
    report("Tungsten (reference)", ref, ref)
    with tempfile.TemporaryDirectory() as tmp:
        scene = mi.load_dict(scene_dict(doc, tmp, a.size, a.spp))
        img = mi.render(scene, spp=a.spp)
        report(f"Mitsuba {a.variant} {a.spp} spp", mean_rgb(img), ref)
        if a.glimpse:
            exr = os.path.join(tmp, "glimpse.exr")
            doc["render"]["max_bounces"] = 64
            doc["render"]["samples_per_pixel"] = a.spp
            doc["image"] = {"width": a.size, "height": a.size}
            scene_path = os.path.join(tmp, "scene.json")
            pathlib.Path(scene_path).write_text(json.dumps(doc))
            subprocess.run(
                [a.glimpse, "render", scene_path, "--mode", "reference", "--output",
                 os.path.join(tmp, "g.png"), "--exr", exr],
                check=True, stderr=subprocess.DEVNULL,
            )
            report(f"Glimpse {a.spp} spp", mean_rgb(exr), ref)


if __name__ == "__main__":
    main()
