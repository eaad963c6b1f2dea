#!/usr/bin/env python3
"""Writes a deterministic glTF 2.0 scene of about 1.06 M triangles for scale tests: a
displaced terrain (a 710 x 710 quad grid, per-vertex normals and uvs), 48 rocks (baked
icospheres, each its own mesh and node), a sun (KHR_lights_punctual directional), an
emissive lamp panel and a perspective camera. Two files: OUT.gltf and OUT.bin beside it.

usage: python3 scripts/gen_big_gltf.py OUT.gltf [--grid N] [--rocks N]
(standard library + numpy; the same arguments always write the same bytes)
"""
import argparse
import json
import os

import numpy as np

# Terrain size in scene units (metres): a 200 m square, heights within about +-12 m.
EXTENT = 200.0


def height(x, z):
    """Terrain height at (x, z): a few octaves of fixed sines (deterministic, smooth)."""
    h = 8.0 * np.sin(0.021 * x + 0.3) * np.cos(0.017 * z - 0.7)
    h += 3.0 * np.sin(0.073 * x - 0.052 * z + 1.1)
    h += 1.2 * np.cos(0.19 * x + 0.23 * z) * np.sin(0.11 * z)
    h += 0.35 * np.sin(0.61 * x + 0.1) * np.sin(0.57 * z + 0.4)
    return h


def terrain(n):
    """An n x n quad grid displaced by `height`: positions, normals, uvs, indices."""
    t = np.linspace(-EXTENT / 2, EXTENT / 2, n + 1)
    x, z = np.meshgrid(t, t)
    y = height(x, z)
    # Normals from the height field's central differences: n = (-dh/dx, 1, -dh/dz).
    e = 1e-3
    dx = (height(x + e, z) - height(x - e, z)) / (2 * e)
    dz = (height(x, z + e) - height(x, z - e)) / (2 * e)
    nrm = np.stack([-dx, np.ones_like(dx), -dz], axis=-1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    pos = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    uv = np.stack([(x / EXTENT + 0.5) * 16, (z / EXTENT + 0.5) * 16], axis=-1).reshape(-1, 2)
    i = np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]
    a, b, c, d = i, i + 1, i + n + 1, i + n + 2
    # Counter-clockwise seen from above (+y), as glTF's front faces.
    idx = np.stack([a, c, b, b, c, d], axis=-1).reshape(-1, 3)
    return pos, nrm.reshape(-1, 3), uv, idx


def icosphere(level):
    """A unit icosphere subdivided `level` times: positions (= normals), indices."""
    p = (1 + 5 ** 0.5) / 2
    v = [(-1, p, 0), (1, p, 0), (-1, -p, 0), (1, -p, 0), (0, -1, p), (0, 1, p),
         (0, -1, -p), (0, 1, -p), (p, 0, -1), (p, 0, 1), (-p, 0, -1), (-p, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(q, float) / np.linalg.norm(q) for q in v]
    for _ in range(level):
        mid, nf = {}, []
        for a, b, c in f:
            m = []
            for u, w in ((a, b), (b, c), (c, a)):
                k = (min(u, w), max(u, w))
                if k not in mid:
                    q = verts[u] + verts[w]
                    verts.append(q / np.linalg.norm(q))
                    mid[k] = len(verts) - 1
                m.append(mid[k])
            nf += [(a, m[0], m[2]), (b, m[1], m[0]), (c, m[2], m[1]), (m[0], m[1], m[2])]
        f = nf
    return np.array(verts), np.array(f)


class Writer:
    """Accumulates buffer views and accessors into one binary buffer."""

    def __init__(self):
        self.bin = bytearray()
        self.views, self.accessors = [], []

    def add(self, arr, comp, kind, target, minmax=False):
        while len(self.bin) % 4:
            self.bin.append(0)
        raw = np.ascontiguousarray(arr).tobytes()
        self.views.append({"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(raw),
                           "target": target})
        self.bin += raw
        acc = {"bufferView": len(self.views) - 1, "componentType": comp,
               "count": int(arr.shape[0]) if kind != "SCALAR" else int(arr.size), "type": kind}
        if minmax:
            acc["min"] = [float(m) for m in arr.min(axis=0)]
            acc["max"] = [float(m) for m in arr.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def mesh(self, pos, nrm, idx, uv=None):
        attrs = {"POSITION": self.add(pos.astype("<f4"), 5126, "VEC3", 34962, True),
                 "NORMAL": self.add(nrm.astype("<f4"), 5126, "VEC3", 34962)}
        if uv is not None:
            attrs["TEXCOORD_0"] = self.add(uv.astype("<f4"), 5126, "VEC2", 34962)
        ind = self.add(idx.astype("<u4").reshape(-1), 5125, "SCALAR", 34963)
        return attrs, ind


def build(grid, rocks):
    w = Writer()
    meshes, nodes = [], []
    pos, nrm, uv, idx = terrain(grid)
    attrs, ind = w.mesh(pos, nrm, idx, uv)
    meshes.append({"name": "terrain", "primitives": [
        {"attributes": attrs, "indices": ind, "material": 0}]})
    nodes.append({"name": "terrain", "mesh": 0})
    sp, sf = icosphere(3)
    rng = np.random.default_rng(20261207)
    for r in range(rocks):
        cx, cz = rng.uniform(-EXTENT * 0.3, EXTENT * 0.3, 2)
        s = rng.uniform(1.5, 4.0, 3) * np.array([1.0, 0.6, 1.0])
        # Baked: the rock's own scaled copy in world space, resting half sunk in the ground.
        p = sp * s + np.array([cx, height(cx, cz), cz])
        n = sp / s
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        attrs, ind = w.mesh(p, n, sf)
        meshes.append({"name": f"rock{r}", "primitives": [
            {"attributes": attrs, "indices": ind, "material": 1}]})
        nodes.append({"name": f"rock{r}", "mesh": len(meshes) - 1})
    # A lamp panel (emissive quad) standing above the terrain's centre, facing down.
    lp = np.array([[-6, 30, -6], [6, 30, -6], [6, 30, 6], [-6, 30, 6]], float)
    ln = np.tile([0.0, -1.0, 0.0], (4, 1))
    attrs, ind = w.mesh(lp, ln, np.array([[0, 1, 2], [0, 2, 3]]))
    meshes.append({"name": "lamp", "primitives": [
        {"attributes": attrs, "indices": ind, "material": 2}]})
    nodes.append({"name": "lamp", "mesh": len(meshes) - 1})
    # The sun: directional, shining along the node's -z, tilted down by a rotation about x.
    a = np.radians(-50) / 2
    nodes.append({"name": "sun", "rotation": [float(np.sin(a)), 0.0, 0.0, float(np.cos(a))],
                  "extensions": {"KHR_lights_punctual": {"light": 0}}})
    nodes.append({"name": "camera", "camera": 0, "translation": [0.0, 45.0, 120.0],
                  "rotation": [float(np.sin(np.radians(-18) / 2)), 0.0, 0.0,
                               float(np.cos(np.radians(-18) / 2))]})
    doc = {
        "asset": {"version": "2.0", "generator": "glimpse scripts/gen_big_gltf.py"},
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "directional", "color": [1.0, 0.95, 0.85], "intensity": 3.0}]}},
        "scene": 0,
        "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes,
        "meshes": meshes,
        "cameras": [{"type": "perspective", "perspective": {
            "yfov": float(np.radians(40)), "aspectRatio": 16 / 9, "znear": 0.1}}],
        "materials": [
            {"name": "grass", "pbrMetallicRoughness": {
                "baseColorFactor": [0.32, 0.42, 0.18, 1], "metallicFactor": 0.0,
                "roughnessFactor": 1.0}},
            {"name": "rock", "pbrMetallicRoughness": {
                "baseColorFactor": [0.5, 0.48, 0.45, 1], "metallicFactor": 0.0,
                "roughnessFactor": 0.8}},
            {"name": "lamp", "emissiveFactor": [1.0, 0.9, 0.7],
             "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1]}},
        ],
        "accessors": w.accessors,
        "bufferViews": w.views,
        "buffers": [{"byteLength": len(w.bin)}],
    }
    return doc, bytes(w.bin)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out", help="the .gltf to write (its .bin goes beside it)")
    ap.add_argument("--grid", type=int, default=710, help="terrain quads per side")
    ap.add_argument("--rocks", type=int, default=48)
    a = ap.parse_args()
    doc, blob = build(a.grid, a.rocks)
    binname = os.path.splitext(os.path.basename(a.out))[0] + ".bin"
    doc["buffers"][0]["uri"] = binname
    with open(os.path.join(os.path.dirname(os.path.abspath(a.out)), binname), "wb") as f:
        f.write(blob)
    with open(a.out, "w") as f:
        json.dump(doc, f, indent=1)
    tris = sum(w["count"] // 3 for m in doc["meshes"] for p in m["primitives"]
               for w in [doc["accessors"][p["indices"]]])
    print(json.dumps({"gltf": a.out, "triangles": tris, "bin_bytes": len(blob)}))


if __name__ == "__main__":
    main()
