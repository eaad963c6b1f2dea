#!/usr/bin/env python3
"""Mitsuba 3 renders a scene document written by `glimpse convert` (diffuse, conductor,
dielectric, emissive meshes and spheres, point lights, environment): an independent
renderer on exactly the geometry Glimpse imported. Prints the display-range mean (each
channel clamped to [0, 1]) and writes the linear image as EXR.

usage: python3 scripts/peer_import.py SCENE.json OUT.exr [--spp N] [--size WxH] [--bounces N]
(needs `pip install mitsuba numpy`)
"""
import argparse
import json
import os
import tempfile

import numpy as np
import mitsuba as mi

mi.set_variant("scalar_rgb")


def rgb(v):
    return {"type": "rgb", "value": [float(c) for c in v]}


def bsdf(m):
    t = m["type"]
    if t == "diffuse":
        return {"type": "diffuse", "reflectance": rgb(m["albedo"])}
    if t == "conductor":
        alpha = max(float(m["roughness"]) ** 2, 1e-3)
        return {"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                "eta": rgb(m["eta"]), "k": rgb(m["k"])}
    if t == "dielectric":
        return {"type": "dielectric", "int_ior": float(m["ior"]), "ext_ior": 1.0}
    if t == "emissive":
        return {"type": "diffuse", "reflectance": rgb([0, 0, 0])}
    raise SystemExit(f"material type {t} not expressed in the peer script")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("out")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--size", default=None)
    ap.add_argument("--bounces", type=int, default=None)
    a = ap.parse_args()
    doc = json.load(open(a.scene))
    w, h = doc["image"]["width"], doc["image"]["height"]
    if a.size:
        w, h = (int(x) for x in a.size.split("x"))
    cam = doc["camera"]
    depth = (a.bounces if a.bounces is not None else doc["render"]["max_bounces"]) + 1
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": depth},
        "sensor": {
            "type": "perspective", "fov": float(cam["fov_y"]), "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=cam["position"], target=cam["look_at"], up=cam.get("up", [0, 1, 0])),
            "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": a.spp},
        },
    }
    mats = doc["materials"]
    tmpdir = tempfile.TemporaryDirectory(prefix="peer-import-")  # removed at exit
    tmp = tmpdir.name
    for i, o in enumerate(doc["objects"]):
        m = mats[o["material"]]
        # Glimpse and pbrt reflect off both sides of a surface, Mitsuba's diffuse and
        # conductor only off the front: wrapped in `twosided` (a dielectric has two sides).
        b = bsdf(m)
        shape = {"bsdf": b if m["type"] in ("dielectric", "emissive")
                 else {"type": "twosided", "bsdf": b}}
        if m["type"] == "emissive":
            shape["emitter"] = {"type": "area", "radiance": rgb(m["radiance"])}
        if o["type"] == "sphere":
            shape.update({"type": "sphere", "center": o["center"], "radius": o["radius"]})
            scene[f"o{i}"] = shape
            continue
        if o["type"] != "mesh":
            raise SystemExit(f"object type {o['type']} not expressed in the peer script")
        # Through an OBJ file: Mitsuba 3.9's Mesh has no set_emitter any more, and a
        # shape loaded from a dict takes its BSDF and emitter as it is built. Without
        # normals each face keeps its own (Glimpse's flat shading), not smoothed ones.
        path = os.path.join(tmp, f"o{i}.obj")
        with open(path, "w") as f:
            f.writelines(f"v {p[0]!r} {p[1]!r} {p[2]!r}\n" for p in o["positions"])
            if "normals" in o:
                f.writelines(f"vn {n[0]!r} {n[1]!r} {n[2]!r}\n" for n in o["normals"])
                f.writelines(f"f {a+1}//{a+1} {b+1}//{b+1} {c+1}//{c+1}\n" for a, b, c in o["indices"])
            else:
                f.writelines(f"f {a+1} {b+1} {c+1}\n" for a, b, c in o["indices"])
        shape.update({"type": "obj", "filename": path, "face_normals": "normals" not in o})
        scene[f"o{i}"] = shape
    for j, l in enumerate(doc.get("lights", [])):
        if l["type"] == "point":
            scene[f"l{j}"] = {"type": "point", "position": l["position"], "intensity": rgb(l["intensity"])}
        elif l["type"] == "environment":
            scene[f"l{j}"] = {"type": "constant", "radiance": rgb(l["radiance"])}
        elif l["type"] == "directional":
            scene[f"l{j}"] = {"type": "directional", "direction": l["direction"], "irradiance": rgb(l["irradiance"])}
    img = np.array(mi.render(mi.load_dict(scene)))[:, :, :3]
    mi.Bitmap(img).write(a.out)
    print("display-range mean", np.clip(img, 0, 1).mean(axis=(0, 1)).round(4).tolist())


if __name__ == "__main__":
    main()
