#!/usr/bin/env python3
"""Mitsuba 3 renders a scene document written by `glimpse convert` (diffuse with a colour
or an image texture, conductor, dielectric, glTF metallic-roughness, emissive meshes and
spheres, point, directional and environment lights): an independent renderer on exactly
the geometry Glimpse imported. Writes the linear image as EXR and prints one JSON object:

  variant          the Mitsuba variant (llvm_ad_rgb when Dr.Jit finds libLLVM, else scalar_rgb)
  width, height, spp
  convert_s        this script turning the document into Mitsuba's inputs (PLY files,
                   texture arrays): not Mitsuba's work, reported apart
  parse_s          Mitsuba loading the shapes, textures and BSDFs (mi.load_dict of each)
  build_s          mi.load_dict of the scene holding them: acceleration structure, emitters
  load_s           parse_s + build_s
  warmup_s         a render of 1 spp first, not timed in render_s: the JIT compiles the
                   LLVM variant's kernels there and the timed render reuses them (the
                   scalar variant has nothing to compile)
  render_s         mi.render of all spp (kernels already compiled), until the image is read
  samples_per_second   width x height x spp / render_s
  peak_rss_bytes   VmHWM of this process at the end; loaded_rss_bytes: VmRSS after load
  mean             the display-range mean (each channel clamped to [0, 1])
  triangles

usage: python3 scripts/peer_import.py SCENE.json OUT.exr [--spp N] [--size WxH]
       [--bounces N] [--variant V] [--seed N]
(needs `pip install mitsuba numpy`; scripts/mitsuba.sh installs both and libLLVM)
"""
import argparse
import base64
import glob
import json
import os
import tempfile
import time

# Dr.Jit's LLVM backend needs a libLLVM it can use (scripts/mitsuba.sh installs one);
# found here as scripts/mitsuba_peer.py does, before mitsuba is imported.
if "DRJIT_LIBLLVM_PATH" not in os.environ:
    _newest = sorted(glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM.so.19*"))
    if _newest:
        os.environ["DRJIT_LIBLLVM_PATH"] = _newest[-1]

import numpy as np  # noqa: E402
import mitsuba as mi  # noqa: E402


def rgb(v):
    return {"type": "rgb", "value": [float(c) for c in v]}


def status_bytes(field):
    """A `/proc/self/status` field (kB) in bytes, or None."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def srgb_to_linear(c):
    """The sRGB transfer function inverted (IEC 61966-2-1)."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


class Textures:
    """Image textures of the document as Mitsuba bitmaps: decoded here from the data URI,
    made linear (`encoding`), multiplied by `factor`, then handed over raw."""

    def __init__(self, tmp):
        self.tmp, self.n = tmp, 0

    def bitmap(self, t):
        head, _, payload = t["data"].partition(",")
        ext = head.split("/")[-1].split(";")[0].replace("x-", "")
        path = os.path.join(self.tmp, f"t{self.n}.{ext}")
        self.n += 1
        with open(path, "wb") as f:
            f.write(base64.b64decode(payload))
        src = mi.Bitmap(path)
        ints = src.component_format() == mi.Struct.Type.UInt8
        img = np.array(src, dtype=np.float32)
        if img.ndim == 2:
            img = img[:, :, None]
        img = img[:, :, :3] if img.shape[2] >= 3 else np.repeat(img[:, :, :1], 3, axis=2)
        if ints:
            img = img / 255.0
        if t.get("encoding", "srgb") == "srgb":
            img = srgb_to_linear(img)
        img = img * np.array(t.get("factor", [1, 1, 1]), np.float32)
        wrap = {"repeat": "repeat", "mirror": "mirror", "clamp": "clamp", "black": "clamp"}
        return {"type": "bitmap", "bitmap": mi.Bitmap(img.astype(np.float32)), "raw": True,
                "filter_type": "bilinear", "wrap_mode": wrap[t.get("wrap", "repeat")]}


def bsdf(m, textures):
    t = m["type"]
    if t == "diffuse":
        if "texture" in m:
            return {"type": "diffuse", "reflectance": textures.bitmap(m["texture"])}
        return {"type": "diffuse", "reflectance": rgb(m["albedo"])}
    if t == "conductor":
        alpha = max(float(m["roughness"]) ** 2, 1e-3)
        return {"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                "eta": rgb(m["eta"]), "k": rgb(m["k"])}
    if t == "dielectric":
        return {"type": "dielectric", "int_ior": float(m["ior"]), "ext_ior": 1.0}
    if t == "metallic_roughness":
        # glTF 2.0 Appendix B; Mitsuba's principled BSDF with specular 0.5 has the same
        # dielectric F0 = 0.04 and a base-colour-tinted metal lobe (close, not identical:
        # its diffuse lobe is Burley's, not Lambert's).
        base = textures.bitmap(m["texture"]) if "texture" in m else rgb(m["base_color"])
        return {"type": "principled", "base_color": base, "metallic": float(m["metallic"]),
                "roughness": max(float(m["roughness"]), 1e-3), "specular": 0.5}
    if t == "emissive":
        return {"type": "diffuse", "reflectance": rgb([0, 0, 0])}
    raise SystemExit(f"material type {t} not expressed in the peer script")


def write_ply(path, o, uv_map):
    """A binary PLY of mesh `o` (positions, optional normals, uvs mapped by `uv_map`)."""
    p = np.asarray(o["positions"], np.float32)
    cols = [("x", p[:, 0]), ("y", p[:, 1]), ("z", p[:, 2])]
    if "normals" in o:
        n = np.asarray(o["normals"], np.float32)
        cols += [("nx", n[:, 0]), ("ny", n[:, 1]), ("nz", n[:, 2])]
    if "uvs" in o and uv_map is not None:
        scale, offset = uv_map
        uv = np.asarray(o["uvs"], np.float32) * np.float32(scale) + np.float32(offset)
        cols += [("u", uv[:, 0]), ("v", uv[:, 1])]
    verts = np.empty(len(p), dtype=[(c, "<f4") for c, _ in cols])
    for c, v in cols:
        verts[c] = v
    idx = np.asarray(o["indices"], np.uint32)
    faces = np.empty(len(idx), dtype=[("n", "u1"), ("i", "<u4", (3,))])
    faces["n"], faces["i"] = 3, idx
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(p)}"]
    head += [f"property float {c}" for c, _ in cols]
    head += [f"element face {len(idx)}", "property list uchar uint vertex_indices",
             "end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode())
        f.write(verts.tobytes())
        f.write(faces.tobytes())
    return len(idx)


def uv_map_of(m):
    """Glimpse's texture mapping `uv x uv_scale + uv_offset` ((0, 0) the image's top-left
    corner, as Mitsuba's bitmap lookup), applied to the mesh's uvs, or None."""
    t = m.get("texture")
    if not t or t.get("type") != "image":
        return None
    return t.get("uv_scale", [1.0, 1.0]), t.get("uv_offset", [0.0, 0.0])


def shapes(doc, tmp, textures):
    """Each object as a Mitsuba shape dict; and the triangle count."""
    mats, out, tris = doc["materials"], {}, 0
    for i, o in enumerate(doc["objects"]):
        if "transform" in o:
            raise SystemExit(f"objects[{i}]: a transform is not expressed in the peer script")
        m = mats[o["material"]]
        # Glimpse and pbrt reflect off both sides of a surface, Mitsuba's diffuse and
        # conductor only off the front: wrapped in `twosided` (a dielectric has two sides).
        b = bsdf(m, textures)
        shape = {"bsdf": b if m["type"] in ("dielectric", "emissive")
                 else {"type": "twosided", "bsdf": b}}
        if m["type"] == "emissive":
            shape["emitter"] = {"type": "area", "radiance": rgb(m["radiance"])}
            if m.get("two_sided"):
                shape["bsdf"] = {"type": "twosided", "bsdf": b}
        if o["type"] == "sphere":
            shape.update({"type": "sphere", "center": o["center"], "radius": o["radius"]})
        elif o["type"] == "mesh":
            path = os.path.join(tmp, f"o{i}.ply")
            tris += write_ply(path, o, uv_map_of(m))
            # Without normals each face keeps its own (Glimpse's flat shading).
            shape.update({"type": "ply", "filename": path, "face_normals": "normals" not in o})
        else:
            raise SystemExit(f"object type {o['type']} not expressed in the peer script")
        out[f"o{i}"] = shape
    return out, tris


def lights(doc):
    out = {}
    for j, lt in enumerate(doc.get("lights", [])):
        if lt["type"] == "point":
            out[f"l{j}"] = {"type": "point", "position": lt["position"],
                            "intensity": rgb(lt["intensity"])}
        elif lt["type"] == "environment":
            out[f"l{j}"] = {"type": "constant", "radiance": rgb(lt["radiance"])}
        elif lt["type"] == "directional":
            out[f"l{j}"] = {"type": "directional", "direction": lt["direction"],
                            "irradiance": rgb(lt["irradiance"])}
        else:
            raise SystemExit(f"light type {lt['type']} not expressed in the peer script")
    return out


def variant_of(asked):
    if asked:
        return asked
    if os.environ.get("DRJIT_LIBLLVM_PATH") and "llvm_ad_rgb" in mi.variants():
        return "llvm_ad_rgb"
    return "scalar_rgb"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("out")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--size", default=None)
    ap.add_argument("--bounces", type=int, default=None)
    ap.add_argument("--variant", default=None, help="default: llvm_ad_rgb if usable")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    variant = variant_of(a.variant)
    mi.set_variant(variant)
    t0 = time.perf_counter()
    doc = json.load(open(a.scene))
    w, h = doc["image"]["width"], doc["image"]["height"]
    if a.size:
        w, h = (int(x) for x in a.size.split("x"))
    cam = doc["camera"]
    depth = (a.bounces if a.bounces is not None else doc["render"]["max_bounces"]) + 1
    tmpdir = tempfile.TemporaryDirectory(prefix="peer-import-")  # removed at exit
    shape_dicts, tris = shapes(doc, tmpdir.name, Textures(tmpdir.name))
    light_dicts = lights(doc)
    del doc  # the JSON document is not Mitsuba's memory
    convert_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    loaded = {k: mi.load_dict(v) for k, v in shape_dicts.items()}
    parse_s = time.perf_counter() - t0
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
        **loaded,
        **light_dicts,
    }
    t0 = time.perf_counter()
    scene = mi.load_dict(scene)
    build_s = time.perf_counter() - t0
    loaded_rss = status_bytes("VmRSS")

    t0 = time.perf_counter()
    np.array(mi.render(scene, spp=1, seed=a.seed + 1000))
    warmup_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    img = np.array(mi.render(scene, spp=a.spp, seed=a.seed))[:, :, :3]
    render_s = time.perf_counter() - t0
    mi.Bitmap(img).write(a.out)
    print(json.dumps({
        "variant": variant, "width": w, "height": h, "spp": a.spp,
        "triangles": tris, "convert_s": convert_s, "parse_s": parse_s, "build_s": build_s,
        "load_s": parse_s + build_s, "warmup_s": warmup_s, "render_s": render_s,
        "samples_per_second": w * h * a.spp / render_s,
        "loaded_rss_bytes": loaded_rss, "peak_rss_bytes": status_bytes("VmHWM"),
        "mean": np.clip(img, 0, 1).mean(axis=(0, 1)).round(5).tolist(),
    }))


if __name__ == "__main__":
    main()
