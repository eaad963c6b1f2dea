#!/usr/bin/env python3
"""Writes a Glimpse scene document as glTF 2.0 with pygltflib, an independent writer: the
round trip of shared/spec/scene-import.md ("a scene written as a document and exported to
glTF renders the same picture both ways"; tests/gltf_roundtrip.rs).

usage: python3 scripts/gltf_export.py SCENE.json OUT.glb|OUT.gltf
(needs pygltflib: `bash scripts/gltf_tools.sh ensure` installs it into target/pydeps)

What a document holds that glTF can say exactly: `mesh` and `quad` objects (a quad as two
triangles) with their `transform` as the node's TRS, `metallic_roughness` materials
(pbrMetallicRoughness), `emissive` ones (emissiveFactor with
KHR_materials_emissive_strength, doubleSided for `two_sided`), `point`, `spot` (with
`"falloff": "squared_linear"`, glTF's own) and `directional` lights (KHR_lights_punctual,
photometric units taken 1:1 as Glimpse does) and the perspective camera. Anything else
(Glimpse's Lambertian `diffuse`, spheres, an environment) has no exact glTF form and is
refused, so the round trip never compares two different scenes.
"""
import json
import math
import struct
import sys

import pygltflib as g

FLOAT, UINT = 5126, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


def fail(msg):
    raise SystemExit(f"gltf_export: {msg}")


def sub(a, b):
    return [a[i] - b[i] for i in range(3)]


def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def unit(v):
    n = math.sqrt(sum(c * c for c in v))
    if n == 0:
        fail(f"zero-length vector {v}")
    return [c / n for c in v]


def quat_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz]


def axis_quat(axis, degrees):
    h = math.radians(degrees) / 2
    q = [0.0, 0.0, 0.0, math.cos(h)]
    q[axis] = math.sin(h)
    return q


def basis_quat(x, y, z):
    """The rotation whose columns are the orthonormal x, y, z (Shepperd's method)."""
    m = [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]]
    t = m[0][0] + m[1][1] + m[2][2]
    if t > 0:
        s = math.sqrt(t + 1) * 2
        return [(m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, s / 4]
    i = max(range(3), key=lambda k: m[k][k])
    j, k = (i + 1) % 3, (i + 2) % 3
    s = math.sqrt(1 + m[i][i] - m[j][j] - m[k][k]) * 2
    q = [0.0] * 4
    q[i] = s / 4
    q[j] = (m[j][i] + m[i][j]) / s
    q[k] = (m[k][i] + m[i][k]) / s
    q[3] = (m[k][j] - m[j][k]) / s
    return q


def looking(direction, up_hint=(0.0, 1.0, 0.0)):
    """A node rotation whose −z is `direction` (glTF cameras and lights look along −z)."""
    z = unit([-c for c in direction])
    up = list(up_hint)
    if abs(sum(up[i] * z[i] for i in range(3))) > 0.999:
        up = [1.0, 0.0, 0.0]
    x = unit(cross(up, z))
    return basis_quat(x, cross(z, x), z)


def trs(transform):
    """scene-format.md's transform (scale, then rotate x, y, z, then translate) as TRS."""
    t = transform or {}
    node = {}
    if "translate" in t:
        node["translation"] = [float(c) for c in t["translate"]]
    q = [0.0, 0.0, 0.0, 1.0]
    for axis, key in enumerate(["rotate_x", "rotate_y", "rotate_z"]):
        if key in t:
            q = quat_mul(axis_quat(axis, float(t[key])), q)
    if q != [0.0, 0.0, 0.0, 1.0]:
        node["rotation"] = q
    if "scale" in t:
        s = t["scale"]
        node["scale"] = [float(s)] * 3 if isinstance(s, (int, float)) else [float(c) for c in s]
    return node


class Writer:
    def __init__(self):
        self.gltf = g.GLTF2(asset=g.Asset(version="2.0", generator="Glimpse round trip (pygltflib)"))
        self.blob = bytearray()
        self.materials = {}

    def view(self, data, target):
        while len(self.blob) % 4:
            self.blob.append(0)
        self.gltf.bufferViews.append(g.BufferView(buffer=0, byteOffset=len(self.blob),
                                                  byteLength=len(data), target=target))
        self.blob.extend(data)
        return len(self.gltf.bufferViews) - 1

    def accessor(self, rows, kind, fmt, ctype, target, bounds):
        data = b"".join(struct.pack("<" + fmt * len(r), *r) for r in rows)
        acc = g.Accessor(bufferView=self.view(data, target), componentType=ctype,
                         count=len(rows), type=kind)
        if bounds:
            acc.min = [min(r[i] for r in rows) for i in range(len(rows[0]))]
            acc.max = [max(r[i] for r in rows) for i in range(len(rows[0]))]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def material(self, name, m):
        if name in self.materials:
            return self.materials[name]
        t = m["type"]
        if t == "metallic_roughness":
            if "texture" in m:
                fail(f"materials.{name}: textures are not exported")
            mat = g.Material(name=name, alphaCutoff=None, pbrMetallicRoughness=g.PbrMetallicRoughness(
                baseColorFactor=[float(c) for c in m["base_color"]] + [1.0],
                metallicFactor=float(m["metallic"]), roughnessFactor=float(m["roughness"])))
        elif t == "emissive":
            strength = max(float(c) for c in m["radiance"])
            mat = g.Material(name=name, alphaCutoff=None, doubleSided=bool(m.get("two_sided", False)),
                             emissiveFactor=[float(c) / strength for c in m["radiance"]],
                             pbrMetallicRoughness=g.PbrMetallicRoughness(
                                 baseColorFactor=[0.0, 0.0, 0.0, 1.0]),
                             extensions={"KHR_materials_emissive_strength":
                                         {"emissiveStrength": strength}})
            self.used("KHR_materials_emissive_strength")
        else:
            fail(f"materials.{name}: type {t} has no exact glTF form")
        self.gltf.materials.append(mat)
        self.materials[name] = len(self.gltf.materials) - 1
        return self.materials[name]

    def used(self, ext):
        if ext not in self.gltf.extensionsUsed:
            self.gltf.extensionsUsed.append(ext)

    def mesh(self, k, obj, materials):
        if obj["type"] == "quad":
            c, u, v = obj["corner"], obj["edge_u"], obj["edge_v"]
            positions = [c, [c[i] + u[i] for i in range(3)],
                         [c[i] + u[i] + v[i] for i in range(3)], [c[i] + v[i] for i in range(3)]]
            indices = [[0, 1, 2], [0, 2, 3]]
            normals = None
        elif obj["type"] == "mesh":
            positions, indices, normals = obj["positions"], obj["indices"], obj.get("normals")
            if "uvs" in obj:
                fail(f"objects[{k}]: texture coordinates are not exported")
        else:
            fail(f"objects[{k}]: type {obj['type']} has no exact glTF form")
        attrs = g.Attributes(POSITION=self.accessor(
            [[float(c) for c in p] for p in positions], "VEC3", "f", FLOAT, ARRAY_BUFFER, True))
        if normals:
            attrs.NORMAL = self.accessor([[float(c) for c in n] for n in normals], "VEC3", "f",
                                         FLOAT, ARRAY_BUFFER, False)
        idx = self.accessor([[int(i)] for tri in indices for i in tri], "SCALAR", "I", UINT,
                            ELEMENT_ARRAY_BUFFER, False)
        mat = self.material(obj["material"], materials[obj["material"]])
        self.gltf.meshes.append(g.Mesh(primitives=[g.Primitive(attributes=attrs, indices=idx,
                                                               material=mat)]))
        node = g.Node(mesh=len(self.gltf.meshes) - 1, **trs(obj.get("transform")))
        return self.node(node)

    def node(self, node):
        self.gltf.nodes.append(node)
        return len(self.gltf.nodes) - 1

    def light(self, k, light):
        t = light["type"]
        if t not in ("point", "spot", "directional"):
            fail(f"lights[{k}]: type {t} has no glTF form")
        power = light["irradiance"] if t == "directional" else light["intensity"]
        strength = max(float(c) for c in power)
        out = {"type": t, "intensity": strength, "color": [float(c) / strength for c in power]}
        node = {}
        if t == "spot":
            if light.get("falloff") != "squared_linear":
                fail(f"lights[{k}]: only glTF's squared_linear spot falloff is exported")
            out["spot"] = {"innerConeAngle": math.radians(float(light["inner_angle"])),
                           "outerConeAngle": math.radians(float(light["outer_angle"]))}
        if t != "directional":
            node["translation"] = [float(c) for c in light["position"]]
        if t != "point":
            node["rotation"] = looking(light["direction"])
        lights = self.gltf.extensions.setdefault("KHR_lights_punctual", {"lights": []})["lights"]
        lights.append(out)
        self.used("KHR_lights_punctual")
        return self.node(g.Node(extensions={"KHR_lights_punctual": {"light": len(lights) - 1}},
                                **node))

    def camera(self, cam, image):
        fwd = unit(sub(cam["look_at"], cam["position"]))
        self.gltf.cameras.append(g.Camera(type="perspective", perspective=g.Perspective(
            yfov=math.radians(float(cam["fov_y"])), znear=0.01,
            aspectRatio=float(image["width"]) / float(image["height"]))))
        return self.node(g.Node(camera=len(self.gltf.cameras) - 1,
                                translation=[float(c) for c in cam["position"]],
                                rotation=looking(fwd, cam.get("up", [0.0, 1.0, 0.0]))))

    def save(self, out):
        self.gltf.buffers.append(g.Buffer(byteLength=len(self.blob)))
        self.gltf.set_binary_blob(bytes(self.blob))
        if out.endswith(".glb"):
            self.gltf.save_binary(out)
        else:
            self.gltf.convert_buffers(g.BufferFormat.DATAURI)
            self.gltf.save(out)


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    with open(sys.argv[1], encoding="utf-8") as f:
        doc = json.load(f)
    w = Writer()
    nodes = [w.camera(doc["camera"], doc["image"])]
    nodes += [w.mesh(k, o, doc["materials"]) for k, o in enumerate(doc["objects"])]
    nodes += [w.light(k, l) for k, l in enumerate(doc.get("lights", []))]
    w.gltf.scenes.append(g.Scene(nodes=nodes))
    w.gltf.scene = 0
    w.save(sys.argv[2])


if __name__ == "__main__":
    main()
