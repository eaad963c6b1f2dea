#!/usr/bin/env python3
"""Hostile and odd-input probe of a live `glimpse serve` (and of `glimpse render`).

    cargo build --release && python3 scripts/probe_service.py [--out /tmp/probe] [--only uploads,cancel,denoise,cli]

What it checks, each case one row of a markdown table (`area | tried | expected | result`):

1. uploads: hostile bodies in every format the API takes -- a scene document
   (application/json), the document in a zip, a `.glb` (model/gltf-binary), a `.gltf` with
   its buffers in a zip, OBJ+MTL in a zip, pbrt with `Include`s and PLY meshes in a zip:
   size bombs (huge meshes, many objects, many numbers, whitespace, texture headers),
   deep nesting, instancing bombs, path escapes (`../`, absolute names, percent-encoded,
   symbolic links), duplicate names, truncated and corrupt files, wrong content types,
   non-UTF-8, NaN/Inf/1e308, zero and negative sizes, odd query parameters. For each: the
   status, the time to answer, the growth of the server's peak resident memory (`VmHWM`,
   reset through /proc/PID/clear_refs before the case, so each case is measured alone),
   that the server still answers /healthz, logged no panic and leaked none of its files.
   Held: a 4xx (or, where marked, any status below 500 for valid-but-odd input, the job
   then reaching a final state), under 1 s, under 150 MB growth.
2. cancel: every mode (reference, progressive, guo, adaptive), with and without
   `render.denoise`, cancelled while queued behind another job, right after submit on an
   idle server, early in the render, mid-render and (denoise jobs) during the final
   denoise (total - denoise/2 after it starts, from a calibration run of the same job).
   Held: 202, then `cancelled` (never `succeeded`) within 1 s of the 202 (polled every
   5 ms), and the job queued behind it starting within 1 s.
3. denoise: `render.denoise: true` at 1x1, 3x2, 400x1, 1024^2, 2048^2 (reference 1 spp,
   adaptive 2 spp), 100000x1 (a server with --max-width/--max-pixels 100000); held:
   `succeeded` with stats.denoised true and a frame of the right size, or `failed` with
   error.code `denoise_failed`. A 4096^2 adaptive denoised job on `--max-job-memory 2`
   must get 422 over_limit naming --max-job-memory.
4. cli: `glimpse render` with impossible options must exit 1 or 2 with one clear
   sentence, no panic or backtrace (never 134).

It starts its own servers (release binary, free loopback ports, throwaway data folders),
runs one heavy thing at a time, bounds every request with a timeout, and stops its
servers at the end. The table goes to OUT/table.md, every answer's detail to
OUT/details.json. Exit status 1 when any case did not hold. Standard library only.
"""
import argparse
import base64
import http.client
import io
import json
import os
import resource
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
import zlib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target/release/glimpse")
CORNELL = os.path.join(ROOT, "scenes/cornell-box.json")
MB = 1e6
ANSWER_MS = 1000.0
GROWTH_MB = 150.0
CANCEL_MS = 1000.0
FOLLOW_MS = 1000.0
TERMINAL = ("succeeded", "failed", "cancelled")
DEADLINE = time.monotonic() + 15 * 60  # the whole run; cases past it are skipped
MATCH = ""  # --match: only the upload cases whose area or description contains it

ROWS = []
DETAILS = []


def row(area, tried, expected, result, ok, detail=None):
    ROWS.append(dict(area=area, tried=tried, expected=expected, result=result, ok=ok))
    DETAILS.append(dict(area=area, tried=tried, expected=expected, result=result, ok=ok, detail=detail))
    mark = "held" if ok else "DID NOT HOLD"
    print(f"[{area}] {tried}: {result} -> {mark}", flush=True)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# --------------------------------------------------------------------------- servers


class Server:
    def __init__(self, name, extra=()):
        self.name = name
        self.extra = list(extra)
        self.port = free_port()
        self.data = tempfile.mkdtemp(prefix=f"glimpse-probe-{name}-")
        self.log_path = os.path.join(self.data, "server.log")
        self.log_pos = 0
        self.restarts = 0
        self.proc = None
        self.start()

    def start(self):
        self.log = open(self.log_path, "ab")
        self.proc = subprocess.Popen(
            [BIN, "serve", "--addr", f"127.0.0.1:{self.port}",
             "--data", os.path.join(self.data, "d"), *self.extra],
            stdout=subprocess.DEVNULL, stderr=self.log)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server {self.name} exited with {self.proc.returncode}")
            try:
                if self.req("GET", "/healthz", timeout=2)[0] == 200:
                    return
            except OSError:
                pass
            time.sleep(0.05)
        raise RuntimeError(f"server {self.name} did not come up")

    def restart(self):
        self.stop()
        self.restarts += 1
        shutil.rmtree(os.path.join(self.data, "d"), ignore_errors=True)
        self.start()

    def stop(self):
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.log.close()

    def close(self):
        """Stop it and remove its data folder."""
        self.stop()
        shutil.rmtree(self.data, ignore_errors=True)

    def warm(self):
        """One refused request first, so that what a case measures is the case."""
        try:
            self.req("POST", "/v1/jobs", b"", {"Content-Type": JSON}, timeout=10)
        except OSError:
            pass
        self.new_log()

    def alive(self):
        return self.proc.poll() is None

    def req(self, method, path, body=None, headers=None, timeout=30):
        c = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)
        t0 = time.monotonic()
        try:
            try:
                c.request(method, path, body=body, headers=headers or {})
            except (BrokenPipeError, ConnectionResetError):
                pass  # the server answered (413) before reading all of the body
            r = c.getresponse()
            data = r.read()
            return r.status, {k.lower(): v for k, v in r.getheaders()}, data, (time.monotonic() - t0) * 1000
        finally:
            c.close()

    def status_kb(self, field):
        with open(f"/proc/{self.proc.pid}/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
        return 0

    def reset_hwm(self):
        """Peak RSS := current RSS (Linux clear_refs 5); False where not allowed."""
        try:
            with open(f"/proc/{self.proc.pid}/clear_refs", "w") as f:
                f.write("5")
            return True
        except OSError:
            return False

    def new_log(self):
        with open(self.log_path, "rb") as f:
            f.seek(self.log_pos)
            text = f.read()
            self.log_pos = f.tell()
        return text.decode("utf-8", "replace")

    def healthy(self):
        try:
            return self.alive() and self.req("GET", "/healthz", timeout=5)[0] == 200
        except OSError:
            return False

    # jobs

    def job(self, jid):
        st, _, b, _ = self.req("GET", f"/v1/jobs/{jid}", timeout=10)
        return json.loads(b) if st == 200 else {"state": f"GET {st}"}

    def wait(self, jid, timeout, interval=0.05):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            j = self.job(jid)
            if j.get("state") in TERMINAL or str(j.get("state", "")).startswith("GET"):
                return j
            time.sleep(interval)
        return None

    def submit(self, doc, timeout=30):
        st, _, b, ms = self.req("POST", "/v1/jobs", json.dumps(doc).encode(),
                                {"Content-Type": "application/json"}, timeout=timeout)
        j = json.loads(b) if b else {}
        if st != 201:
            raise RuntimeError(f"submit answered {st}: {b[:300]!r}")
        return j["id"]

    def cancel(self, jid):
        return self.req("POST", f"/v1/jobs/{jid}/cancel", timeout=10)


def time_left():
    return DEADLINE - time.monotonic()


# --------------------------------------------------------------------------- payloads


def cornell():
    with open(CORNELL) as f:
        return json.load(f)


def tiny_doc(**render):
    d = cornell()
    d["image"] = {"width": 8, "height": 8}
    d["render"].update(mode="reference", samples_per_pixel=1)
    d["render"].update(render)
    return d


def doc_with_objects(raw_objects):
    """A tiny document whose `objects` is the given raw JSON text (built as a string)."""
    d = tiny_doc()
    d["objects"] = ["__OBJECTS__"]
    return json.dumps(d).replace('["__OBJECTS__"]', raw_objects).encode()


def unknown_objects_doc():
    """A tiny document with an unknown field of 1.18 M small objects: 8.3 MB, under --max-body."""
    return doc_bytes(tiny_doc())[:-1] + b',"x":[' + b",".join([b'{"":0}'] * 1_180_000) + b"]}"


def doc_bytes(d):
    return json.dumps(d).encode()


def mutate(f):
    d = tiny_doc()
    f(d)
    return doc_bytes(d)


def png(w, h, raw=None, corrupt=False):
    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    if raw is None:
        comp = zlib.compressobj(9)
        line = b"\x00" + b"\x00" * (3 * w)
        parts = []
        for _ in range(h):
            parts.append(comp.compress(line))
        parts.append(comp.flush())
        idat = b"".join(parts)
    else:
        idat = raw
    if corrupt:
        idat = idat[: len(idat) // 2] + b"\xde\xad\xbe\xef" * 8
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def textured_doc(png_bytes):
    d = tiny_doc()
    uri = "data:image/png;base64," + base64.b64encode(png_bytes).decode()
    d["materials"]["back_wall"] = {"type": "diffuse", "texture": {"type": "image", "data": uri}}
    return doc_bytes(d)


# zips


def mkzip(entries, method=zipfile.ZIP_DEFLATED):
    """entries: (name, data) with data bytes/str or an iterable of byte chunks (streamed);
    or (name, data, {"symlink": True})."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", method) as z:
        import warnings
        warnings.simplefilter("ignore")  # duplicate names are on purpose
        for e in entries:
            name, data = e[0], e[1]
            opts = e[2] if len(e) > 2 else {}
            zi = zipfile.ZipInfo(name, date_time=(2024, 1, 1, 0, 0, 0))
            zi.compress_type = opts.get("method", method)
            if opts.get("symlink"):
                zi.create_system = 3
                zi.external_attr = (0o120777 << 16)
            if isinstance(data, str):
                data = data.encode()
            if isinstance(data, (bytes, bytearray)):
                z.writestr(zi, bytes(data))
            else:
                with z.open(zi, "w") as w:
                    for chunk in data:
                        w.write(chunk.encode() if isinstance(chunk, str) else chunk)
    return buf.getvalue()


def repeat(piece, times, chunk=1 << 20):
    """Chunks of `piece` repeated `times` times, ~chunk bytes at once."""
    piece = piece.encode() if isinstance(piece, str) else piece
    per = max(1, chunk // len(piece))
    block = piece * per
    left = times
    while left > 0:
        n = min(per, left)
        yield block if n == per else piece * n
        left -= n


def zip_dir(b):
    """Central directory entries of a zip: (central offset, local offset)."""
    eocd = b.rfind(b"PK\x05\x06")
    n = struct.unpack_from("<H", b, eocd + 10)[0]
    off = struct.unpack_from("<I", b, eocd + 16)[0]
    out = []
    for _ in range(n):
        nlen, elen, clen = struct.unpack_from("<HHH", b, off + 28)
        loc = struct.unpack_from("<I", b, off + 42)[0]
        out.append((off, loc))
        off += 46 + nlen + elen + clen
    return eocd, out


def patch(b, at, fmt, value):
    b = bytearray(b)
    struct.pack_into(fmt, b, at, value)
    return bytes(b)


def zip_lying_size():
    z = mkzip([("scene.obj", repeat("v 0 0 0\n", 6_000_000))])
    _, ents = zip_dir(z)
    c, l = ents[0]
    z = patch(z, c + 24, "<I", 1000)
    return patch(z, l + 22, "<I", 1000)


def zip_flagged(kind):
    z = mkzip([("scene.obj", OBJ_TRI)], method=zipfile.ZIP_STORED)
    eocd, ents = zip_dir(z)
    c, l = ents[0]
    if kind == "encrypted":
        z = patch(z, c + 8, "<H", 1)
        return patch(z, l + 6, "<H", 1)
    if kind == "method99":
        z = patch(z, c + 10, "<H", 99)
        return patch(z, l + 8, "<H", 99)
    if kind == "count":
        z = patch(z, eocd + 8, "<H", 0xFFFF)
        return patch(z, eocd + 10, "<H", 0xFFFF)
    if kind == "cdoffset":
        return patch(z, eocd + 16, "<I", 0xFFFFFF00)
    if kind == "declared4g":
        z = mkzip([("scene.obj", OBJ_TRI), ("unused.bin", b"x" * 16)], method=zipfile.ZIP_STORED)
        _, ents = zip_dir(z)
        c, l = ents[1]
        z = patch(z, c + 24, "<I", 0xFFFFFFFF)
        return patch(z, l + 22, "<I", 0xFFFFFFFF)
    raise ValueError(kind)


def zip_raw_name(name_placeholder, raw, body):
    """A zip whose one scene entry's name has raw (non-UTF-8) bytes."""
    z = mkzip([(name_placeholder, body)], method=zipfile.ZIP_STORED)
    return z.replace(name_placeholder.encode(), raw)


# glTF


def glb(doc, bin_=b"", raw_json=None):
    js = raw_json if raw_json is not None else json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js
    if bin_:
        bin_ = bin_ + b"\0" * (-len(bin_) % 4)
        body += struct.pack("<II", len(bin_), 0x004E4942) + bin_
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


TRI_POS = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)


def gltf_tri(n_tris=1, uri=None, nodes=None, scene_nodes=None, extras=None, positions=TRI_POS,
             index_count=None, extra=None):
    """A glTF document of one mesh of `n_tris` triangles (u16 indices 0 1 2 repeated) and
    its binary buffer. `uri` names the buffer (for a .gltf) instead of the GLB chunk."""
    idx = struct.pack("<3H", 0, 1, 2) * n_tris
    idx_len = len(idx)
    idx += b"\0" * (-len(idx) % 4)
    bin_ = positions + idx
    buf = {"byteLength": len(bin_)}
    if uri is not None:
        buf["uri"] = uri
    d = {
        "asset": {"version": "2.0"},
        "buffers": [buf],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": len(positions)},
            {"buffer": 0, "byteOffset": len(positions), "byteLength": idx_len},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(positions) // 12, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5123, "count": index_count or 3 * n_tris, "type": "SCALAR"},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": nodes if nodes is not None else [{"mesh": 0}],
        "scenes": [{"nodes": scene_nodes if scene_nodes is not None else [0]}],
        "scene": 0,
    }
    if extras is not None:
        d["extras"] = "__EXTRAS__"
    if extra:
        extra(d)
    js = json.dumps(d).encode()
    if extras is not None:
        js = js.replace(b'"__EXTRAS__"', extras)
    return js, bin_


def glb_of(**kw):
    js, b = gltf_tri(**kw)
    return glb(None, b, raw_json=js)


def gltf_zip(uri="mesh.bin", files=None, **kw):
    js, b = gltf_tri(uri=uri, **kw)
    entries = [("scene.gltf", js)]
    if files is None:
        entries.append(("mesh.bin", b))
    else:
        entries += files(b)
    return mkzip(entries)


def glb_texture(w, h):
    """A .glb whose material's base colour texture is a PNG in the BIN chunk."""
    img = png(w, h, raw=zlib.compress(b"\0" * 64)) if w * h > 1 << 22 else png(w, h)
    js, b = gltf_tri()
    d = json.loads(js)
    off = len(b)
    pad = b"\0" * (-len(img) % 4)
    d["buffers"][0]["byteLength"] = len(b) + len(img) + len(pad)
    d["bufferViews"].append({"buffer": 0, "byteOffset": off, "byteLength": len(img)})
    d["images"] = [{"bufferView": 2, "mimeType": "image/png"}]
    d["textures"] = [{"source": 0}]
    d["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    d["meshes"][0]["primitives"][0]["material"] = 0
    return glb(d, b + img + pad)


# OBJ and pbrt

OBJ_TRI = "mtllib scene.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n"
MTL = "newmtl m\nKd 0.5 0.5 0.5\n"


def obj_zip(obj, mtl=MTL, more=()):
    return mkzip([("scene.obj", obj), ("scene.mtl", mtl), *more])


HEAD = ('LookAt 0 0 5  0 0 0  0 1 0\nCamera "perspective" "float fov" 40\nWorldBegin\n'
        'LightSource "point" "rgb I" [10 10 10] "point3 from" [0 0 5]\n')
PLY_ASCII = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
             "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
             "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")


def pbrt_zip(main, more=()):
    return mkzip([("scene.pbrt", main), *more])


def ply_binary(nv, nf, data):
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {nv}\nproperty float x\n"
            f"property float y\nproperty float z\nelement face {nf}\n"
            "property list uchar int vertex_indices\nend_header\n").encode()
    return head + data


def instancing_bomb_pbrt(levels=40):
    s = HEAD + 'ObjectBegin "o0"\nShape "trianglemesh" "point3 P" [0 0 0 1 0 0 0 1 0] "integer indices" [0 1 2]\nObjectEnd\n'
    for i in range(1, levels + 1):
        s += f'ObjectBegin "o{i}"\nObjectInstance "o{i-1}"\nObjectInstance "o{i-1}"\nObjectEnd\n'
    return s + f'ObjectInstance "o{levels}"\n'


def dag_bomb_nodes(levels=40):
    nodes = []
    for i in range(levels):
        kids = [2 * (i + 1), 2 * (i + 1) + 1]
        nodes += [{"children": kids}, {"children": kids}]
    nodes += [{"mesh": 0}, {"mesh": 0}]
    return nodes


# --------------------------------------------------------------------------- 1. uploads

JSON = "application/json"
ZIP = "application/zip"
GLB = "model/gltf-binary"
SMALLQ = "?width=8&height=8&spp=1&mode=reference"
REFUSAL_WORDS = ("not allowed", "leaves the bundle", "symbolic link", "not in the bundle")
LEAKS = (b"root:x:0", b"root:*:0", b"/bin/bash", b"[package]", b"CREATE TABLE")


def upload_cases():
    """(area, tried, content type or None, body thunk, query, expect) with expect '4xx'
    (refused) or 'lt500' (valid but odd: any status below 500; a job must then end)."""
    C = []

    def add(area, tried, ctype, body, query="", expect="4xx", **kw):
        C.append(dict(area=area, tried=tried, ctype=ctype, body=body, query=query, expect=expect, **kw))

    A = "upload: JSON body"
    add(A, "20 MB mesh document (over --max-body 8 MiB)", JSON,
        lambda: doc_with_objects('[{"type":"mesh","positions":[[0,0,0],[1,0,0],[0,1,0]],"indices":['
                                 + ",".join(["[0,1,2]"] * 2_600_000) + '],"material":"floor"}]'))
    add(A, "Content-Length: 100 MB declared, no body sent", None, None, raw="cl_only")
    add(A, "chunked transfer of 20 MB (no Content-Length)", JSON, None, raw="chunked")
    add(A, "mesh of 1 000 001 triangles in 8.0 MB (over --max-triangles)", JSON,
        lambda: doc_with_objects('[{"type":"mesh","positions":[[0,0,0],[1,0,0],[0,1,0]],"indices":['
                                 + ",".join(["[0,1,2]"] * 1_000_001) + '],"material":"floor"}]'))
    add(A, "10 001 spheres (over --max-objects)", JSON,
        lambda: doc_with_objects("[" + ",".join(['{"type":"sphere","center":[0,1,0],"radius":0.1,"material":"floor"}'] * 10_001) + "]"))
    add(A, "1 000 000 unused mesh positions, one triangle (7.9 MB; valid per scene-format.md)", JSON,
        lambda: doc_with_objects('[{"type":"mesh","positions":[' + ",".join(["[0,0,0]"] * 999_997)
                                 + ',[1,0,0],[0,1,0],[0,0,1]],"indices":[[999997,999998,999999]],"material":"floor"}]'),
        expect="lt500")
    add(A, "unknown field holding 2.09 M `[0]` arrays (8.4 MB)", JSON,
        lambda: doc_bytes(tiny_doc())[:-1] + b',"x":[' + b",".join([b"[0]"] * 2_090_000) + b"]}")
    add(A, "unknown field holding 1.18 M `{\"\":0}` objects (8.3 MB)", JSON, unknown_objects_doc)
    add(A, "7.9 MB of whitespace around a valid document", JSON,
        lambda: b" " * 7_900_000 + doc_bytes(tiny_doc()) + b"\n" * 10, expect="lt500")
    add(A, "7.9 MB name string", JSON, lambda: mutate(lambda d: d.update(name="x" * 7_900_000)), expect="lt500")
    add(A, "deep nesting: name = 100 000 nested arrays", JSON,
        lambda: b'{"version":1,"name":' + b"[" * 100_000 + b"]" * 100_000 + b"}")
    add(A, "deep nesting: 8 MB of '[' (never closed)", JSON, lambda: b"[" * 8_000_000)
    add(A, "deep nesting: 100 000 nested objects in an unknown field", JSON,
        lambda: doc_bytes(tiny_doc())[:-1] + b',"x":' + b'{"a":' * 100_000 + b"1" + b"}" * 100_000 + b"}")
    add(A, "NaN literal (radius: NaN)", JSON,
        lambda: doc_with_objects('[{"type":"sphere","center":[0,1,0],"radius":NaN,"material":"floor"}]'))
    add(A, "Infinity literal in camera position", JSON,
        lambda: doc_bytes(tiny_doc()).replace(b'"position": [0, 1, 6.8]', b'"position": [0, 1, Infinity]'))
    add(A, "1e309 (overflows f64) as a sphere radius", JSON,
        lambda: doc_with_objects('[{"type":"sphere","center":[0,1,0],"radius":1e309,"material":"floor"}]'))
    add(A, "1e308 sphere radius", JSON,
        lambda: doc_with_objects('[{"type":"sphere","center":[0,1,0],"radius":1e308,"material":"floor"}]'), expect="lt500")
    add(A, "1e308 camera position", JSON,
        lambda: mutate(lambda d: d["camera"].update(position=[1e308, 1e308, 1e308])), expect="lt500")
    add(A, "transform scale 1e308 on a box (overflows when applied)", JSON,
        lambda: doc_with_objects('[{"type":"box","min":[0,0,0],"max":[1,1,1],"material":"floor","transform":{"scale":1e308,"translate":[1e308,0,0]}}]'),
        expect="lt500")
    add(A, "-1e308 / 1e308 mesh positions", JSON,
        lambda: doc_with_objects('[{"type":"mesh","positions":[[-1e308,0,0],[1e308,0,0],[0,1e308,0]],"indices":[[0,1,2]],"material":"floor"}]'),
        expect="lt500")
    add(A, "light intensity 1e308 and exposure 1e308", JSON,
        lambda: mutate(lambda d: (d.update(lights=[{"type": "point", "position": [0, 1.5, 0], "intensity": [1e308] * 3}]),
                                  d["display"].update(exposure=1e308))), expect="lt500")
    add(A, "fov_y 0 / 180 / 1e308", JSON, lambda: mutate(lambda d: d["camera"].update(fov_y=0)), group="fov", label="0")
    add(A, "fov_y 0 / 180 / 1e308", JSON, lambda: mutate(lambda d: d["camera"].update(fov_y=180)), group="fov", label="180")
    add(A, "fov_y 0 / 180 / 1e308", JSON, lambda: mutate(lambda d: d["camera"].update(fov_y=1e308)), group="fov", label="1e308")
    for label, img in [("0x8", {"width": 0, "height": 8}), ("8x-1", {"width": 8, "height": -1}),
                       ("1e10x8", {"width": 1e10, "height": 8}), ("4097x1", {"width": 4097, "height": 1}),
                       ("1.5x8", {"width": 1.5, "height": 8}), ('"8"x8', {"width": "8", "height": 8}),
                       ("2^64x8", {"width": 18446744073709551616, "height": 8}),
                       ("missing height", {"width": 8})]:
        add(A, "image sizes 0x8, 8x-1, 1e10x8, 4097x1, 1.5x8, \"8\"x8, 2^64x8, no height", JSON,
            (lambda img=img: mutate(lambda d: d.update(image=img))), group="sizes", label=label)
    for label, f in [("radius 0", lambda d: d["objects"].append({"type": "sphere", "center": [0, 1, 0], "radius": 0, "material": "floor"})),
                     ("radius -1", lambda d: d["objects"].append({"type": "sphere", "center": [0, 1, 0], "radius": -1, "material": "floor"})),
                     ("zero-area quad", lambda d: d["objects"].append({"type": "quad", "corner": [0, 0, 0], "edge_u": [0, 0, 0], "edge_v": [0, 0, 1], "material": "floor"})),
                     ("spp 0", lambda d: d["render"].update(samples_per_pixel=0)),
                     ("spp -1", lambda d: d["render"].update(samples_per_pixel=-1)),
                     ("spp 2^32", lambda d: d["render"].update(samples_per_pixel=1 << 32)),
                     ("max_bounces -1", lambda d: d["render"].update(max_bounces=-1)),
                     ("index out of range", lambda d: d["objects"].append({"type": "mesh", "positions": [[0, 0, 0]], "indices": [[0, 0, 4294967295]], "material": "floor"})),
                     ("up parallel to view", lambda d: d["camera"].update(up=[0, 0, 1])),
                     ("max_iterations 0", lambda d: d["progressive"].update(max_iterations=0)),
                     ("version 2", lambda d: d.update(version=2))]:
        add(A, "zero/negative/degenerate values: radius 0, radius -1, zero-area quad, spp 0, spp -1, spp 2^32, "
            "max_bounces -1, index 2^32-1, up parallel to view, max_iterations 0, version 2", JSON,
            (lambda f=f: mutate(f)), group="degenerate", label=label)
    add(A, "duplicate key \"version\" at the top level", JSON,
        lambda: b'{"version":1,' + doc_bytes(tiny_doc())[1:])
    add(A, "duplicate material name (two \"floor\" keys, different types)", JSON,
        lambda: doc_bytes(tiny_doc()).replace(b'"materials": {', b'"materials": {"floor": {"type": "mirror", "reflectance": [1, 1, 1]}, ', 1))
    add(A, "unknown material name / unknown field / wrong type", JSON,
        lambda: mutate(lambda d: d["objects"][0].update(material="nope")), group="unknown", label="material")
    add(A, "unknown material name / unknown field / wrong type", JSON,
        lambda: mutate(lambda d: d["render"].update(sammples=3)), group="unknown", label="field")
    add(A, "unknown material name / unknown field / wrong type", JSON,
        lambda: mutate(lambda d: d.update(objects={"a": 1})), group="unknown", label="type")
    add(A, "obj object naming /etc/passwd and ../../etc/passwd", JSON,
        lambda: doc_with_objects('[{"type":"obj","path":"/etc/passwd","material":"floor"}]'), group="objpath", label="/etc/passwd")
    add(A, "obj object naming /etc/passwd and ../../etc/passwd", JSON,
        lambda: doc_with_objects('[{"type":"obj","path":"../../../../etc/passwd","material":"floor"}]'), group="objpath", label="../..")
    add(A, "non-UTF-8 byte (0xFF) inside the name string", JSON,
        lambda: doc_bytes(tiny_doc()).replace(b'"cornell-box"', b'"corn\xffell"'))
    add(A, "UTF-16 (BOM) encoded document", JSON, lambda: b"\xff\xfe" + json.dumps(tiny_doc()).encode("utf-16-le"))
    add(A, "UTF-8 BOM before a valid document", JSON, lambda: b"\xef\xbb\xbf" + doc_bytes(tiny_doc()), expect="lt500")
    add(A, "NUL bytes after a valid document", JSON, lambda: doc_bytes(tiny_doc()) + b"\0" * 1000)
    add(A, "truncated document (first half)", JSON, lambda: doc_bytes(tiny_doc())[: len(doc_bytes(tiny_doc())) // 2])
    add(A, "empty body", JSON, lambda: b"")
    add(A, "texture: PNG header 65535x65535 (88 bytes, over 16.7 M texels)", JSON, lambda: textured_doc(png(65535, 65535, raw=zlib.compress(b"\0" * 64))))
    add(A, "texture: PNG 4097x4096 (just over the texel limit)", JSON, lambda: textured_doc(png(4097, 4096)))
    add(A, "texture: PNG 4096x4096 zeros (exactly the 16.7 M texel limit, 49 KB)", JSON,
        lambda: textured_doc(png(4096, 4096)), expect="lt500")
    add(A, "texture: corrupt PNG data (IDAT cut and garbage)", JSON, lambda: textured_doc(png(64, 64, corrupt=True)))
    add(A, "texture: data URI that is not base64 / names image/svg+xml / a file: URI", JSON,
        lambda: mutate(lambda d: d["materials"].update(back_wall={"type": "diffuse", "texture": {"type": "image", "data": "data:image/png;base64,!!!!"}})),
        group="uri", label="bad base64")
    add(A, "texture: data URI that is not base64 / names image/svg+xml / a file: URI", JSON,
        lambda: mutate(lambda d: d["materials"].update(back_wall={"type": "diffuse", "texture": {"type": "image", "data": "data:image/svg+xml;base64,PHN2Zy8+"}})),
        group="uri", label="svg")
    add(A, "texture: data URI that is not base64 / names image/svg+xml / a file: URI", JSON,
        lambda: mutate(lambda d: d["materials"].update(back_wall={"type": "diffuse", "texture": {"type": "image", "data": "file:///etc/passwd"}})),
        group="uri", label="file:")

    A = "upload: content type"
    for label, ct in [("text/plain", "text/plain"), ("none", None), ("multipart/form-data", "multipart/form-data; boundary=x"),
                      ("application/json; charset=latin1", "application/json; charset=latin1"),
                      ("model/gltf-binary", GLB), ("application/zip", ZIP)]:
        add(A, "a valid document sent as text/plain, with no type, multipart, charset=latin1, model/gltf-binary, application/zip",
            ct, lambda: doc_bytes(tiny_doc()), expect="4xx" if label != "application/json; charset=latin1" else "lt500",
            group="ct-doc", label=label)
    add(A, "a valid zip sent as application/json / a .glb sent as application/zip / a zip sent as model/gltf-binary", JSON,
        lambda: obj_zip(OBJ_TRI), query=SMALLQ, group="ct-swap", label="zip as json")
    add(A, "a valid zip sent as application/json / a .glb sent as application/zip / a zip sent as model/gltf-binary", ZIP,
        lambda: glb_of(), query=SMALLQ, group="ct-swap", label="glb as zip")
    add(A, "a valid zip sent as application/json / a .glb sent as application/zip / a zip sent as model/gltf-binary", GLB,
        lambda: obj_zip(OBJ_TRI), query=SMALLQ, group="ct-swap", label="zip as glb")
    add(A, "Content-Type header repeated (json + zip)", None, None, raw="dup_ct")

    A = "upload: query"
    for q in ["width=0", "width=-1", "width=99999999999999999999", "width=4097", "height=4097&width=4096",
              "width=100000&height=100000", "spp=0", "spp=-1", "spp=4097", "mode=bogus", "denoise=maybe",
              "sampler=bogus", "seed=abc", "seed=-1", "width=1e3"]:
        add(A, "zip upload with ?" + ", ?".join(["width=0", "width=-1", "width=2^66", "width=4097", "4096x4097",
                                                  "100000x100000", "spp=0", "spp=-1", "spp=4097", "mode=bogus",
                                                  "denoise=maybe", "sampler=bogus", "seed=abc", "seed=-1",
                                                  "width=1e3"]),
            ZIP, lambda: obj_zip(OBJ_TRI), query="?" + q + "&spp=1" * ("spp" not in q), group="query", label=q)

    add(A, "repeated query parameter ?width=8&width=9 (ambiguous)", ZIP, lambda: obj_zip(OBJ_TRI), query="?width=8&width=9&spp=1")

    A = "upload: zip container"
    add(A, "document in a zip: 250 MiB of whitespace around it (255 KB packed)", ZIP,
        lambda: mkzip([("scene.json", (c for part in (repeat(" ", 250 << 20), [doc_bytes(tiny_doc())]) for c in part))]))
    add(A, "document in a zip: 12 M unused positions (~96 MB unpacked)", ZIP,
        lambda: mkzip([("scene.json", (c for part in ([doc_with_objects('[{"type":"mesh","positions":[__P__[1,0,0],[0,1,0],[0,0,1]],"indices":[[0,1,2]],"material":"floor"}]').split(b"__P__")[0]],
                                                      repeat("[0,0,0],", 12_000_000),
                                                      [doc_with_objects('[{"type":"mesh","positions":[__P__[1,0,0],[0,1,0],[0,0,1]],"indices":[[0,1,2]],"material":"floor"}]').split(b"__P__")[1]])
                                        for c in part))]))
    add(A, "document in a zip, valid (control)", ZIP, lambda: mkzip([("scene.json", doc_bytes(tiny_doc()))]),
        query=SMALLQ, expect="lt500")
    add(A, "10 001 entries (over 10 000)", ZIP,
        lambda: mkzip([("scene.obj", OBJ_TRI)] + [(f"f{i}.txt", b"") for i in range(10_000)], method=zipfile.ZIP_STORED))
    add(A, "declared unpacked size 300 MiB (two unused 150 MiB entries)", ZIP,
        lambda: obj_zip(OBJ_TRI, more=[("a.bin", repeat(b"\0", 150 << 20)), ("b.bin", repeat(b"\0", 150 << 20))]))
    add(A, "directory lies: entry declares 1000 bytes, inflates to 48 MB", ZIP, zip_lying_size)
    add(A, "declared size 0xFFFFFFFF on an unused entry", ZIP, lambda: zip_flagged("declared4g"))
    add(A, "encrypted-entry flag", ZIP, lambda: zip_flagged("encrypted"))
    add(A, "compression method 99 (AES) / 12 (bzip2) / 14 (LZMA)", ZIP, lambda: zip_flagged("method99"), group="method", label="99")
    add(A, "compression method 99 (AES) / 12 (bzip2) / 14 (LZMA)", ZIP,
        lambda: mkzip([("scene.obj", OBJ_TRI)], method=zipfile.ZIP_BZIP2), group="method", label="bzip2")
    add(A, "compression method 99 (AES) / 12 (bzip2) / 14 (LZMA)", ZIP,
        lambda: mkzip([("scene.obj", OBJ_TRI)], method=zipfile.ZIP_LZMA), group="method", label="lzma")
    add(A, "end record claims 65 535 entries", ZIP, lambda: zip_flagged("count"))
    add(A, "central directory offset past the end", ZIP, lambda: zip_flagged("cdoffset"))
    add(A, "truncated zip (first half)", ZIP, lambda: (lambda z: z[: len(z) // 2])(obj_zip(OBJ_TRI)))
    add(A, "empty zip (end record only)", ZIP, lambda: mkzip([]))
    add(A, "random bytes after a PK header", ZIP, lambda: b"PK\x03\x04" + os.urandom(4000))
    add(A, "no scene file (only a .txt)", ZIP, lambda: mkzip([("readme.txt", "hi")]))
    add(A, "two scene files at the root (scene.obj + scene.gltf)", ZIP,
        lambda: mkzip([("scene.obj", OBJ_TRI), ("scene.mtl", MTL), ("other.gltf", gltf_tri(uri="data:application/octet-stream;base64," + base64.b64encode(gltf_tri()[1]).decode())[0])]))
    add(A, "duplicate entry names (scene.obj twice, different contents)", ZIP,
        lambda: mkzip([("scene.obj", OBJ_TRI), ("scene.obj", "v 0 0 0\nf 1 1 1\n"), ("scene.mtl", MTL)]))
    add(A, "scene entry named ../scene.obj", ZIP, lambda: mkzip([("../scene.obj", OBJ_TRI.replace("mtllib scene.mtl\n", ""))]))
    add(A, "scene entry named /tmp/scene.obj (absolute)", ZIP, lambda: mkzip([("/tmp/scene.obj", OBJ_TRI.replace("mtllib scene.mtl\n", ""))]))
    add(A, "scene entry that is a symlink to /etc/passwd", ZIP, lambda: mkzip([("scene.obj", "/etc/passwd", {"symlink": True})]))
    add(A, "scene entry name with a raw 0xFF byte (not UTF-8)", ZIP,
        lambda: zip_raw_name("scXne.obj", b"sc\xffne.obj", OBJ_TRI.replace("mtllib scene.mtl\n", "")),
        query=SMALLQ, expect="lt500")
    add(A, "30 000-character nested folder name for the MTL", ZIP,
        lambda: mkzip([("scene.obj", OBJ_TRI.replace("scene.mtl", "a/" * 15000 + "m.mtl")), ("a/" * 15000 + "m.mtl", MTL)]),
        query=SMALLQ, expect="lt500")

    A = "upload: .glb"
    add(A, "mesh of 1 000 001 triangles (6 MB of u16 indices)", GLB, lambda: glb_of(n_tris=1_000_001))
    add(A, "4 M numbers in extras (8 MB JSON chunk)", GLB, lambda: glb_of(extras=b"[" + b"0," * 3_999_999 + b"0]"))
    add(A, "extras nested 100 000 arrays deep", GLB, lambda: glb_of(extras=b"[" * 100_000 + b"]" * 100_000))
    add(A, "node chain 100 000 deep (each node the child of the one before)", GLB,
        lambda: glb_of(nodes=[{"children": [i + 1]} for i in range(99_999)] + [{"mesh": 0}]))
    add(A, "node cycle (0 -> 1 -> 0)", GLB, lambda: glb_of(nodes=[{"children": [1]}, {"children": [0], "mesh": 0}]))
    add(A, "instancing bomb: DAG of 40 levels, each node two children (2^40 mesh instances)", GLB,
        lambda: glb_of(nodes=dag_bomb_nodes(40)))
    add(A, "scene lists one node 100 000 times", GLB, lambda: glb_of(scene_nodes=[0] * 100_000))
    add(A, "accessor count 1e9 on a 44-byte buffer", GLB, lambda: glb_of(index_count=1_000_000_000))
    add(A, "bufferView past its buffer (byteOffset 2^31)", GLB,
        lambda: glb_of(extra=lambda d: d["bufferViews"][1].update(byteOffset=1 << 31)))
    add(A, "buffer byteLength 1e12 with a 44-byte BIN", GLB,
        lambda: glb_of(extra=lambda d: d["buffers"][0].update(byteLength=10 ** 12)))
    add(A, "buffer uri /etc/passwd / ../x.bin / file:///etc/passwd / bad base64 data URI in a lone .glb", GLB,
        lambda: glb_of(uri="/etc/passwd"), group="glburi", label="/etc/passwd")
    add(A, "buffer uri /etc/passwd / ../x.bin / file:///etc/passwd / bad base64 data URI in a lone .glb", GLB,
        lambda: glb_of(uri="../x.bin"), group="glburi", label="../x.bin")
    add(A, "buffer uri /etc/passwd / ../x.bin / file:///etc/passwd / bad base64 data URI in a lone .glb", GLB,
        lambda: glb_of(uri="file:///etc/passwd"), group="glburi", label="file:")
    add(A, "buffer uri /etc/passwd / ../x.bin / file:///etc/passwd / bad base64 data URI in a lone .glb", GLB,
        lambda: glb_of(uri="data:application/octet-stream;base64,!!!!"), group="glburi", label="bad base64")
    add(A, "header length 0xFFFFFFFF", GLB, lambda: patch(glb_of(), 8, "<I", 0xFFFFFFFF))
    add(A, "JSON chunk length past the file", GLB, lambda: patch(glb_of(), 12, "<I", 0x7FFFFFF0))
    add(A, "truncated (first half)", GLB, lambda: (lambda g: g[: len(g) // 2])(glb_of()))
    add(A, "wrong magic / version 1", GLB, lambda: b"glTX" + glb_of()[4:], group="magic", label="magic")
    add(A, "wrong magic / version 1", GLB, lambda: patch(glb_of(), 4, "<I", 1), group="magic", label="v1")
    add(A, "non-UTF-8 bytes in the JSON chunk", GLB, lambda: glb(None, gltf_tri()[1], raw_json=gltf_tri()[0].replace(b'"2.0"', b'"2.\xff"')))
    add(A, "NaN and Inf float positions in the BIN chunk", GLB,
        lambda: glb_of(positions=struct.pack("<9f", float("nan"), 0, 0, float("inf"), 0, 0, 0, float("-inf"), 0)), query=SMALLQ, expect="lt500")
    add(A, "node scale [1e308,1e308,1e308] and translation 1e308", GLB,
        lambda: glb_of(nodes=[{"mesh": 0, "scale": [1e308] * 3, "translation": [1e308, 0, 0]}]), query=SMALLQ, expect="lt500")
    add(A, "accessor max 1e309 (overflows f64)", GLB,
        lambda: (lambda js_b: glb(None, js_b[1], raw_json=js_b[0].replace(b'"max": [1, 1, 0]', b'"max": [1e309, 1, 0]')))(gltf_tri()))
    add(A, "texture PNG header 65535x65535 in the BIN chunk", GLB, lambda: glb_texture(65535, 65535))
    add(A, "valid single triangle (control)", GLB, lambda: glb_of(), query=SMALLQ, expect="lt500")

    A = "upload: .gltf in zip"
    for label, uri in [("../mesh.bin", "../mesh.bin"), ("/etc/passwd", "/etc/passwd"), ("%2e%2e/mesh.bin", "%2e%2e/mesh.bin"),
                       ("file:///etc/passwd", "file:///etc/passwd"), ("sub/../../mesh.bin", "sub/../../mesh.bin"),
                       ("..\\mesh.bin", "..\\mesh.bin"), ("C:/mesh.bin", "C:/mesh.bin"), ("missing.bin", "missing.bin"),
                       ("http://127.0.0.1:1/x.bin", "http://127.0.0.1:1/x.bin")]:
        add(A, "buffer uri ../mesh.bin, /etc/passwd, %2e%2e/mesh.bin, file:///etc/passwd, sub/../../mesh.bin, "
            "..\\mesh.bin, C:/mesh.bin, a missing name, http://", ZIP, (lambda uri=uri: gltf_zip(uri=uri)),
            group="gltfuri", label=label)
    add(A, "buffer entry mesh.bin is a symlink to /etc/passwd", ZIP,
        lambda: gltf_zip(files=lambda b: [("mesh.bin", "/etc/passwd", {"symlink": True})]))
    add(A, "image uri ../../etc/hostname", ZIP,
        lambda: gltf_zip(extra=lambda d: (d.update(images=[{"uri": "../../etc/hostname"}], textures=[{"source": 0}],
                                                   materials=[{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]),
                                          d["meshes"][0]["primitives"][0].update(material=0))))
    add(A, "mesh.bin shorter than its byteLength (truncated)", ZIP, lambda: gltf_zip(files=lambda b: [("mesh.bin", b[:20])]))
    add(A, "60 MB zero buffer with a 15 M-index accessor (5 M triangles)", ZIP,
        lambda: mkzip([("scene.gltf", json.dumps({
            "asset": {"version": "2.0"}, "buffers": [{"uri": "mesh.bin", "byteLength": 60_000_036}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 60_000_000}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
                          {"bufferView": 1, "componentType": 5125, "count": 15_000_000, "type": "SCALAR"}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
            "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0})),
            ("mesh.bin", (c for part in ([TRI_POS], repeat(b"\0", 60_000_000)) for c in part))]))
    add(A, "two .gltf files at the root", ZIP,
        lambda: mkzip([("a.gltf", gltf_tri(uri="mesh.bin")[0]), ("b.gltf", gltf_tri(uri="mesh.bin")[0]), ("mesh.bin", gltf_tri()[1])]))
    add(A, "extras nested 100 000 arrays deep", ZIP,
        lambda: mkzip([("scene.gltf", gltf_tri(uri="mesh.bin", extras=b"[" * 100_000 + b"]" * 100_000)[0]), ("mesh.bin", gltf_tri()[1])]))
    add(A, "valid .gltf + .bin (control)", ZIP, lambda: gltf_zip(), query=SMALLQ, expect="lt500")

    A = "upload: OBJ+MTL in zip"
    add(A, "5 M unused `v` lines (40 MB unpacked)", ZIP,
        lambda: mkzip([("scene.obj", (c for part in (repeat("v 0 0 0\n", 5_000_000), [OBJ_TRI]) for c in part)), ("scene.mtl", MTL)]))
    add(A, "one face of 2 M vertices (fan of 2 M triangles)", ZIP,
        lambda: obj_zip("v 0 0 0\nv 1 0 0\nv 0 1 0\nf " + "1 2 3 " * 666_667 + "\n"))
    add(A, "20 000 objects (`o` + a face each)", ZIP,
        lambda: obj_zip("v 0 0 0\nv 1 0 0\nv 0 1 0\n" + "".join(f"o g{i}\nf 1 2 3\n" for i in range(20_000))))
    add(A, "10 000 materials in the MTL, 10 000 usemtl switches", ZIP,
        lambda: obj_zip("mtllib scene.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n" + "".join(f"usemtl m{i}\nf 1 2 3\n" for i in range(10_000)),
                        "".join(f"newmtl m{i}\nKd 0.5 0.5 0.5\n" for i in range(10_000))), query=SMALLQ, expect="lt500")
    for label, obj, more in [("mtllib ../x.mtl", OBJ_TRI.replace("scene.mtl", "../x.mtl"), ()),
                             ("mtllib /etc/passwd", OBJ_TRI.replace("scene.mtl", "/etc/passwd"), ()),
                             ("mtllib -> symlink", OBJ_TRI.replace("scene.mtl", "link.mtl"), [("link.mtl", "/etc/passwd", {"symlink": True})])]:
        add(A, "mtllib ../x.mtl, /etc/passwd, a symlink entry to /etc/passwd", ZIP,
            (lambda obj=obj, more=more: obj_zip(obj, more=more)), query=SMALLQ, group="mtllib", label=label, expect="refuse_or_warn")
    for label, mtl in [("map_Kd /etc/passwd", MTL + "map_Kd /etc/passwd\n"), ("map_Kd ../../x.png", MTL + "map_Kd ../../x.png\n")]:
        add(A, "map_Kd /etc/passwd, map_Kd ../../x.png", ZIP, (lambda mtl=mtl: obj_zip(OBJ_TRI, mtl)),
            query=SMALLQ, group="mapkd", label=label, expect="refuse_or_warn")
    for label, f in [("f 1 2 99999999", "f 1 2 99999999"), ("f -5 -6 -7", "f -5 -6 -7"), ("f 0 0 0", "f 0 0 0"),
                     ("f 1 2 4294967297", "f 1 2 4294967297")]:
        add(A, "face indices out of range: 99999999, -5, 0, 2^32+1", ZIP,
            (lambda f=f: obj_zip("v 0 0 0\nv 1 0 0\nv 0 1 0\n" + f + "\n")), group="objidx", label=label)
    add(A, "v nan inf 1e308 / 1e309", ZIP, lambda: obj_zip("v nan inf 1e308\nv 1 0 0\nv 0 1 1e309\nf 1 2 3\n"),
        query=SMALLQ, expect="lt500")
    add(A, "non-UTF-8 bytes in group, usemtl and mtllib names", ZIP,
        lambda: obj_zip(b"mtllib sc\xffene.mtl\ng gr\xfe\xff\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\xff\nf 1 2 3\n"),
        query=SMALLQ, expect="lt500")
    add(A, "truncated: face of two vertices at EOF", ZIP, lambda: obj_zip("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2"),
        query=SMALLQ, expect="lt500")
    add(A, "duplicate newmtl names", ZIP, lambda: obj_zip(OBJ_TRI, MTL + "newmtl m\nKd 1 0 0\nKe 5 5 5\n"),
        query=SMALLQ, expect="lt500")
    add(A, "no faces at all", ZIP, lambda: obj_zip("v 0 0 0\nv 1 0 0\n"), query=SMALLQ, expect="lt500")
    add(A, "valid triangle (control)", ZIP, lambda: obj_zip(OBJ_TRI), query=SMALLQ, expect="lt500")

    A = "upload: pbrt+PLY in zip"
    SPH = 'Shape "sphere"\n'
    for label, main, more in [("Include ../x.pbrt", HEAD + 'Include "../x.pbrt"\n', ()),
                              ("Include /etc/passwd", HEAD + 'Include "/etc/passwd"\n', ()),
                              ("Include symlink", HEAD + 'Include "inc.pbrt"\n', [("inc.pbrt", "/etc/passwd", {"symlink": True})]),
                              ("Import ../../etc/passwd", HEAD + 'Import "../../etc/passwd"\n', ()),
                              ("plymesh /etc/passwd", HEAD + 'Shape "plymesh" "string filename" "/etc/passwd"\n', ()),
                              ("plymesh ../m.ply", HEAD + 'Shape "plymesh" "string filename" "../m.ply"\n', ()),
                              ("plymesh symlink", HEAD + 'Shape "plymesh" "string filename" "m.ply"\n', [("m.ply", "/etc/passwd", {"symlink": True})]),
                              ("imagemap /etc/hostname", HEAD + 'Texture "t" "spectrum" "imagemap" "string filename" "/etc/hostname"\n' + SPH, ())]:
        add(A, "Include ../x.pbrt, Include /etc/passwd, Include of a symlink, Import ../../etc/passwd, plymesh /etc/passwd, "
            "plymesh ../m.ply, plymesh symlink, imagemap /etc/hostname", ZIP,
            (lambda main=main, more=more: pbrt_zip(main, more)), query=SMALLQ, group="pbrtpath", label=label,
            expect="refuse_or_warn")
    add(A, "self-Include: a.pbrt includes a.pbrt (16-byte file)", ZIP,
        lambda: pbrt_zip(HEAD + 'Include "a.pbrt"\n', [("a.pbrt", 'Include "a.pbrt"\n')]))
    add(A, "mutual Include: a.pbrt <-> b.pbrt", ZIP,
        lambda: pbrt_zip(HEAD + 'Include "a.pbrt"\n', [("a.pbrt", 'Include "b.pbrt"\n'), ("b.pbrt", 'Include "a.pbrt"\n')]))
    add(A, "800 000 nested AttributeBegin (never ended)", ZIP,
        lambda: pbrt_zip((c for part in ([HEAD], repeat("AttributeBegin\n", 800_000)) for c in part)))
    add(A, "instancing bomb: 40 levels of ObjectBegin each instancing the level below twice (2^40 triangles)", ZIP,
        lambda: pbrt_zip(instancing_bomb_pbrt(40)))
    add(A, "1 000 000 ObjectInstance of a one-triangle object", ZIP,
        lambda: pbrt_zip((c for part in ([HEAD + 'ObjectBegin "o"\nShape "trianglemesh" "point3 P" [0 0 0 1 0 0 0 1 0] "integer indices" [0 1 2]\nObjectEnd\n'],
                                         repeat('ObjectInstance "o"\n', 1_000_000)) for c in part)))
    add(A, "30 M unused numbers in P before the indices (60 MB text)", ZIP,
        lambda: pbrt_zip((c for part in ([HEAD + 'Shape "trianglemesh"\n  "point3 P" ['], repeat("0 ", 30_000_000),
                                         ['] "integer indices" [0 1 2]\n']) for c in part)))
    add(A, "2 M `Translate 0 0 0` in one file", ZIP,
        lambda: pbrt_zip((c for part in ([HEAD], repeat("Translate 0 0 0\n", 2_000_000), [SPH]) for c in part)))
    add(A, "PLY header: element vertex 4294967295 (ascii)", ZIP,
        lambda: pbrt_zip(HEAD + 'Shape "plymesh" "string filename" "m.ply"\n', [("m.ply", PLY_ASCII.replace("element vertex 3", "element vertex 4294967295"))]))
    add(A, "PLY header: element face 1e9 (binary, 52 bytes of data)", ZIP,
        lambda: pbrt_zip(HEAD + 'Shape "plymesh" "string filename" "m.ply"\n', [("m.ply", ply_binary(3, 1_000_000_000, TRI_POS + b"\x03" + struct.pack("<3i", 0, 1, 2)))]))
    add(A, "PLY binary truncated mid-vertex", ZIP,
        lambda: pbrt_zip(HEAD + 'Shape "plymesh" "string filename" "m.ply"\n', [("m.ply", ply_binary(3, 1, TRI_POS[:20]))]))
    add(A, "PLY face indices out of range (2^31-1, -1)", ZIP,
        lambda: pbrt_zip(HEAD + 'Shape "plymesh" "string filename" "m.ply"\n', [("m.ply", ply_binary(3, 1, TRI_POS + b"\x03" + struct.pack("<3i", 0, 2147483647, -1)))]))
    add(A, "PLY header of garbage and non-UTF-8 bytes", ZIP,
        lambda: pbrt_zip(HEAD + 'Shape "plymesh" "string filename" "m.ply"\n', [("m.ply", b"ply\nformat \xff\xfe 1.0\nelement \x00\nend_header\n" + os.urandom(100))]))
    for label, body in [("Translate 1e309 0 0", HEAD + "Translate 1e309 0 0\n" + SPH),
                        ("radius [nan]", HEAD + 'Shape "sphere" "float radius" [nan]\n'),
                        ("Scale inf inf inf", HEAD + "Scale inf inf inf\n" + SPH)]:
        add(A, "numbers: Translate 1e309, radius nan, Scale inf", ZIP, (lambda body=body: pbrt_zip(body)),
            group="pbrtnum", label=label)
    add(A, "Translate 1e308 0 0 before a sphere", ZIP, lambda: pbrt_zip(HEAD + "Translate 1e308 0 0\n" + SPH),
        query=SMALLQ, expect="lt500")
    for label, body in [("unterminated string", HEAD + 'Shape "sph'), ("unterminated [", HEAD + 'Shape "sphere" "float radius" [1 2 3'),
                        ("truncated mid-directive", HEAD[:40]), ("non-UTF-8 in a string", (HEAD + 'Shape "sph\xffere"\n').encode("latin-1"))]:
        add(A, "truncated / corrupt: unterminated string, unterminated [, cut mid-directive, 0xFF inside a string", ZIP,
            (lambda body=body: pbrt_zip(body)), group="pbrtcut", label=label)
    add(A, "MakeNamedMaterial \"m\" twice / ObjectBegin \"o\" twice", ZIP,
        lambda: pbrt_zip(HEAD + 'MakeNamedMaterial "m" "string type" "diffuse"\nMakeNamedMaterial "m" "string type" "conductor"\nNamedMaterial "m"\n' + SPH),
        query=SMALLQ, expect="lt500", group="pbrtdup", label="material")
    add(A, "MakeNamedMaterial \"m\" twice / ObjectBegin \"o\" twice", ZIP,
        lambda: pbrt_zip(HEAD + 'ObjectBegin "o"\n' + SPH + 'ObjectEnd\nObjectBegin "o"\n' + SPH + 'ObjectEnd\nObjectInstance "o"\n'),
        query=SMALLQ, expect="lt500", group="pbrtdup", label="object")
    add(A, "valid sphere + PLY (control)", ZIP,
        lambda: pbrt_zip(HEAD + SPH + 'Shape "plymesh" "string filename" "m.ply"\n', [("m.ply", PLY_ASCII)]), query=SMALLQ, expect="lt500")
    return C


def raw_request(srv, kind):
    """Requests http.client will not send: a lying Content-Length, a chunked body, a
    repeated header. Returns (status, body, ms)."""
    s = socket.create_connection(("127.0.0.1", srv.port), timeout=30)
    t0 = time.monotonic()
    try:
        if kind == "cl_only":
            s.sendall(b"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                      b"Content-Length: 100000000\r\n\r\n")
        elif kind == "dup_ct":
            body = doc_bytes(tiny_doc())
            s.sendall(b"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                      b"Content-Type: application/zip\r\nContent-Length: " + str(len(body)).encode() + b"\r\n\r\n" + body)
        elif kind == "chunked":
            s.sendall(b"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                      b"Transfer-Encoding: chunked\r\n\r\n")
            piece = b" " * (1 << 20)
            try:
                for _ in range(20):
                    s.sendall(b"%x\r\n" % len(piece) + piece + b"\r\n")
                s.sendall(b"0\r\n\r\n")
            except (BrokenPipeError, ConnectionResetError):
                pass
        data = b""
        while b"\r\n\r\n" not in data:
            got = s.recv(65536)
            if not got:
                break
            data += got
        head, _, rest = data.partition(b"\r\n\r\n")
        status = int(head.split()[1]) if head.startswith(b"HTTP/") else None
        ms = (time.monotonic() - t0) * 1000
        clen = 0
        for line in head.split(b"\r\n")[1:]:
            k, _, v = line.partition(b":")
            if k.strip().lower() == b"content-length":
                clen = int(v)
        while len(rest) < clen:
            got = s.recv(65536)
            if not got:
                break
            rest += got
        return status, rest, ms
    finally:
        s.close()


def fmt_mb(kb):
    return f"{kb * 1024 / MB:+.1f} MB"


def run_upload_case(srv, c):
    """One case: returns (ok, short result, detail)."""
    try:
        body = c["body"]() if c["body"] else None
    except Exception as e:  # a bug of this script, not of the server
        return False, f"probe error building the body: {e!r}", [f"probe error {e!r}"], {}
    log_before = srv.new_log()  # skip what came before
    del log_before
    exact = srv.reset_hwm()
    rss0 = srv.status_kb("VmRSS") if exact else srv.status_kb("VmHWM")
    status, payload, ms, err = None, b"", 0.0, None
    try:
        if c.get("raw"):
            status, payload, ms = raw_request(srv, c["raw"])
        else:
            headers = {"Content-Type": c["ctype"]} if c["ctype"] else {}
            status, _, payload, ms = srv.req("POST", "/v1/jobs" + c["query"], body, headers, timeout=30)
    except (OSError, http.client.HTTPException) as e:
        err = f"{type(e).__name__}: {e}"
    code, message, job_state, warnings = "", "", None, []
    try:
        j = json.loads(payload) if payload else {}
        if isinstance(j, dict) and "error" in j and j["error"]:
            code, message = j["error"].get("code", ""), j["error"].get("message", "")
        if isinstance(j, dict):
            warnings = j.get("warnings") or []
        if status == 201:
            fin = srv.wait(j["id"], 60)
            if fin is None:
                srv.cancel(j["id"])
                job_state = "HANG (not final after 60 s; cancelled)"
            else:
                job_state = fin["state"] + (f" ({fin['error']['code']})" if fin.get("error") else "")
    except (ValueError, KeyError):
        pass
    growth_kb = srv.status_kb("VmHWM") - rss0 if srv.alive() else 0
    healthy = srv.healthy()
    log = srv.new_log()
    panic = "panicked" in log or "stack overflow" in log
    leak = any(s in payload for s in LEAKS)
    problems = []
    if err:
        problems.append(err)
    if status is None:
        problems.append("no answer")
    elif status >= 500:
        problems.append(f"5xx ({status})")
    elif c["expect"] == "4xx" and not 400 <= status < 500:
        problems.append(f"expected 4xx, got {status}")
    elif c["expect"] == "refuse_or_warn" and status == 201 and not any(
            k in w for w in warnings for k in REFUSAL_WORDS):
        problems.append("accepted without a warning that the name was refused")
    if ms > ANSWER_MS:
        problems.append(f"answer took {ms:.0f} ms (> 1 s)")
    if growth_kb * 1024 / MB > GROWTH_MB:
        problems.append(f"memory growth {growth_kb * 1024 / MB:.0f} MB (> 150 MB)")
    if not healthy:
        problems.append("server not healthy after (crash or hang)" + ("" if srv.alive() else f", exit {srv.proc.returncode}"))
    if panic:
        problems.append("panic in server log")
    if leak:
        problems.append("response leaked a server file")
    if job_state and (job_state.startswith("HANG")):
        problems.append(job_state)
    res = f"{status if status is not None else 'none'}"
    if code:
        res += f" {code}"
    res += f", {ms:.0f} ms, {fmt_mb(growth_kb)}"
    if job_state:
        res += f", job {job_state}"
    refusals = [w for w in warnings if any(k in w for k in REFUSAL_WORDS)]
    if refusals:
        res += f", warned: {refusals[0][:90]}"
    detail = dict(warnings=warnings, status=status, code=code, message=message[:400], ms=round(ms, 1),
                  growth_mb=round(growth_kb * 1024 / MB, 1), hwm_exact=exact, job=job_state,
                  body_bytes=len(body) if body else 0, problems=problems,
                  log=[l for l in log.splitlines() if "panick" in l or "ERROR" in l][:5])
    if not srv.alive() or not healthy:
        srv.restart()
    return (not problems), res, problems, detail


def concurrent_case(tried, ctype, body, n=4):
    """n copies of one refused upload at once (a fresh server): statuses, slowest answer, peak growth."""
    import threading
    srv = Server("concurrent")
    srv.warm()
    srv.reset_hwm()
    rss0 = srv.status_kb("VmRSS")
    out = [None] * n

    def one(i):
        try:
            st, _, _, ms = srv.req("POST", "/v1/jobs", body, {"Content-Type": ctype}, timeout=60)
            out[i] = (st, ms)
        except OSError as e:
            out[i] = (None, 0.0)
    ts = [threading.Thread(target=one, args=(i,)) for i in range(n)]
    t0 = time.monotonic()
    for t in ts:
        t.start()
    for t in ts:
        t.join(90)
    wall = (time.monotonic() - t0) * 1000
    growth = (srv.status_kb("VmHWM") - rss0) * 1024 / MB
    problems = []
    sts = [o[0] if o else None for o in out]
    if any(st is None or not 400 <= st < 500 for st in sts):
        problems.append(f"statuses {sts}")
    slow = max((o[1] for o in out if o), default=0)
    if slow > 2 * ANSWER_MS:
        problems.append(f"slowest answer {slow:.0f} ms (> 2 s)")
    if growth > GROWTH_MB:
        problems.append(f"memory growth {growth:.0f} MB (> 150 MB)")
    if not srv.healthy():
        problems.append("server not healthy")
        srv.restart()
    srv.close()
    res = f"{sts}, slowest {slow:.0f} ms, all in {wall:.0f} ms, {growth:+.1f} MB"
    row("upload: concurrent", f"{n} at once: {tried}", "4xx each, the slowest < 2 s, < 150 MB growth in all",
        res if not problems else "**DID NOT HOLD**: " + "; ".join(problems) + " — " + res, not problems,
        dict(statuses=sts, out=out, growth_mb=growth))


def section_uploads():
    """Each row on a fresh server (warmed by one refused request): memory an earlier case
    freed but the allocator kept resident would hide what the next case costs."""
    cases = [c for c in upload_cases() if MATCH in c["area"] + " " + c["tried"]]
    groups = {}
    order = []
    for c in cases:
        key = (c["area"], c.get("group") or id(c))
        if key not in groups:
            groups[key] = []
            order.append(key)
        groups[key].append(c)
    for key in order:
        if time_left() < 240:
            row(key[0], groups[key][0]["tried"], "", "skipped: out of time", False)
            continue
        cs = groups[key]
        srv = Server("upload")
        srv.warm()
        exp = cs[0]["expect"]
        expected = {"4xx": "4xx < 1 s, < 150 MB, healthy",
                    "lt500": "no 5xx (valid but odd), < 1 s, < 150 MB, job ends, healthy",
                    "refuse_or_warn": "4xx, or 201 with a warning that the name was refused (file never read); < 1 s, < 150 MB"}[exp]
        if len(cs) == 1:
            c = cs[0]
            ok, res, problems, det = run_upload_case(srv, c)
            row(c["area"], c["tried"], expected, res if ok else "**DID NOT HOLD**: " + "; ".join(problems) + " — " + res, ok, det)
        else:
            parts, allok, dets, bad = [], True, [], []
            for c in cs:
                ok, res, problems, det = run_upload_case(srv, c)
                det["label"] = c.get("label")
                dets.append(det)
                parts.append(f"{c.get('label')}: {res}")
                if not ok:
                    allok = False
                    bad.append(f"{c.get('label')}: " + "; ".join(problems))
            result = "; ".join(parts)
            if not allok:
                result = "**DID NOT HOLD**: " + " / ".join(bad) + " — " + result
            row(cs[0]["area"], cs[0]["tried"], expected, result, allok, dets)
        srv.close()
    if not MATCH or MATCH == "concurrent":
        concurrent_case("the 2.5 KB .glb DAG instancing bomb", GLB, glb_of(nodes=dag_bomb_nodes(40)))
        concurrent_case("the 8.3 MB JSON document of 1.18 M objects in an unknown field", JSON, unknown_objects_doc())
        concurrent_case("the 60 KB pbrt zip of 30 M numbers in P", ZIP,
                        pbrt_zip((c for part in ([HEAD + 'Shape "trianglemesh"\n  "point3 P" ['], repeat("0 ", 30_000_000),
                                                 ['] "integer indices" [0 1 2]\n']) for c in part)))


# --------------------------------------------------------------------------- 2. cancel

CANCEL_SPP = {"reference": 16, "progressive": 48, "guo": 32, "adaptive": 16}


def mode_doc(mode, denoise, size=512, spp=None):
    d = cornell()
    d["image"] = {"width": size, "height": size}
    d["render"].update(mode=mode, samples_per_pixel=spp or CANCEL_SPP[mode], denoise=denoise, seed=1)
    return d


def follower_doc():
    return tiny_doc(seed=7)


def parse_ts(s):
    # 2026-12-07T21:17:37.152Z
    from datetime import datetime, timezone
    return datetime.strptime(s, "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=timezone.utc).timestamp()


def poll_until(srv, jid, pred, timeout, interval=0.005):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        j = srv.job(jid)
        if pred(j):
            return j, time.monotonic()
        time.sleep(interval)
    return None, time.monotonic()


def cancel_and_measure(srv, jid):
    """POST cancel; then poll every 5 ms to the final state. (status, ms to 202, ms 202->final, job)."""
    st, _, b, ms202 = srv.cancel(jid)
    t202 = time.monotonic()
    j, tfin = poll_until(srv, jid, lambda j: j.get("state") in TERMINAL, 30)
    return st, ms202, (tfin - t202) * 1000, j, b


def follower_start(srv, target, fid):
    """ms from the target's final state to the follower's start (server clocks), and its end."""
    f, _ = poll_until(srv, fid, lambda j: j.get("started_at") or j.get("state") in TERMINAL, 30, 0.01)
    fin = srv.wait(fid, 60)
    if not f or not f.get("started_at") or not target or not target.get("finished_at"):
        return None, fin
    return (parse_ts(f["started_at"]) - parse_ts(target["finished_at"])) * 1000, fin


def section_cancel(srv):
    modes = ["reference", "progressive", "guo", "adaptive"]
    for mode in modes:
        for dn in (False, True):
            if time_left() < 300:
                row("cancel", f"{mode}, denoise {dn}", "", "skipped: out of time", False)
                continue
            label = f"{mode}{' + denoise' if dn else ''}"
            # calibration
            cal_id = srv.submit(mode_doc(mode, dn))
            cal = srv.wait(cal_id, 120)
            if not cal or cal["state"] != "succeeded":
                row("cancel", f"{label}: calibration run", "succeeded", f"**DID NOT HOLD**: {cal and cal['state']}", False, cal)
                continue
            total = cal["stats"]["total_ms"]
            den = cal["stats"].get("denoise_ms") or 0.0
            trace = total - den
            phases = [("queued behind another job", None), ("right after submit, idle server", 0.0),
                      ("early in the render", max(30.0, 0.1 * trace)), ("mid-render", 0.5 * trace)]
            if dn:
                phases.append(("during the final denoise (total - denoise/2)", total - den / 2))
            for phase, offset in phases:
                tried = f"{label} (calibrated 512², total {total:.0f} ms, denoise {den:.0f} ms): cancel {phase}" + (
                    f" at {offset:.0f} ms after running" if offset else "")
                expected = "202, then cancelled (never succeeded) < 1 s after the 202; next job starts < 1 s"
                det = {"total_ms": total, "denoise_ms": den, "offset_ms": offset}
                problems = []
                if offset is None:
                    blocker = srv.submit(mode_doc("reference", False, spp=64))
                    tid = srv.submit(mode_doc(mode, dn))
                    fid = srv.submit(follower_doc())
                    before = srv.job(tid)
                    st, ms202, lat, j, b = cancel_and_measure(srv, tid)
                    # the blocker goes; the follower (queued behind both) must start promptly
                    bst, _, blat, bj, _ = cancel_and_measure(srv, blocker)
                    fstart, fin = follower_start(srv, bj, fid)
                    at = f"state {before.get('state')}"
                    if j and j.get("started_at"):
                        problems.append("the cancelled queued job started anyway")
                else:
                    tid = srv.submit(mode_doc(mode, dn))
                    fid = srv.submit(follower_doc())
                    if offset == 0.0:
                        before = {"state": "(not looked at)"}
                        st, ms202, lat, j, b = cancel_and_measure(srv, tid)
                        at = "immediately"
                    else:
                        r, trun = poll_until(srv, tid, lambda j: j.get("state") != "queued", 30)
                        time.sleep(max(0.0, trun + offset / 1000 - time.monotonic()))
                        before = srv.job(tid)
                        st, ms202, lat, j, b = cancel_and_measure(srv, tid)
                        p = before.get("progress") or {}
                        at = (f"{before.get('state')}, it {p.get('iteration')}, {100 * (p.get('pixel_fraction') or 0):.0f}% px, "
                              f"finishing={p.get('finishing')}" if p else f"{before.get('state')}, no frame published yet")
                        if dn and offset > trace:
                            at += f" (past the calibrated trace end {trace:.0f} ms)"
                    fstart, fin = follower_start(srv, j, fid)
                state = j.get("state") if j else "HANG (no final state in 30 s)"
                if st != 202:
                    problems.append(f"cancel answered {st} {b[:120]!r}")
                if state != "cancelled":
                    problems.append(f"final state {state}" + (" (SUCCEEDED AFTER CANCEL)" if state == "succeeded" else ""))
                if lat > CANCEL_MS:
                    problems.append(f"{lat:.0f} ms from 202 to final state (> 1 s)")
                if fstart is None:
                    problems.append("next job never started")
                elif fstart > FOLLOW_MS:
                    problems.append(f"next job started {fstart:.0f} ms after (> 1 s)")
                if fin is None or fin.get("state") != "succeeded":
                    problems.append(f"next job ended {fin and fin.get('state')}")
                time.sleep(0.3)
                again = srv.job(tid).get("state")
                if again != state:
                    problems.append(f"state changed later to {again}")
                if not srv.healthy():
                    problems.append("server not healthy")
                    srv.restart()
                log = srv.new_log()
                if "panicked" in log:
                    problems.append("panic in server log")
                res = (f"{st} in {ms202:.0f} ms; {state} {lat:.0f} ms after the 202; at cancel: {at}; "
                       f"next job started {fstart:.0f} ms after" if fstart is not None else
                       f"{st} in {ms202:.0f} ms; {state} {lat:.0f} ms after the 202; at cancel: {at}; next job: none")
                det.update(status=st, ms202=ms202, latency_ms=lat, state=state, before=before,
                           follower_ms=fstart, problems=problems)
                row("cancel", tried, expected, res if not problems else "**DID NOT HOLD**: " + "; ".join(problems) + " — " + res,
                    not problems, det)


# --------------------------------------------------------------------------- 3. denoiser sizes


def png_size(b):
    if b[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    return struct.unpack(">II", b[16:24])


def denoise_case(srv, mode, w, h, spp, area="denoise", budget=None):
    tried = f"{mode} {w}×{h}, {spp} spp, render.denoise true"
    expected = "succeeded + stats.denoised true + frame of that size, or failed denoise_failed"
    if budget:
        expected += f"; the server's peak resident memory within the {budget / 1e9:g} GB job budget"
    d = cornell()
    d["image"] = {"width": w, "height": h}
    d["render"].update(mode=mode, samples_per_pixel=spp, denoise=True, seed=3)
    srv.reset_hwm()
    rss0 = srv.status_kb("VmRSS")
    t0 = time.monotonic()
    st, _, b, ms = srv.req("POST", "/v1/jobs", doc_bytes(d), {"Content-Type": JSON}, timeout=30)
    problems = []
    if st != 201:
        row(area, tried, expected, f"**DID NOT HOLD**: submit {st} {b[:200]!r}", False)
        return
    jid = json.loads(b)["id"]
    j = srv.wait(jid, min(300, max(30, time_left() - 60)))
    wall = time.monotonic() - t0
    hwm = srv.status_kb("VmHWM") * 1024
    growth = (hwm / 1024 - rss0) * 1024 / MB
    if budget and hwm > budget:
        problems.append(f"peak resident {hwm / 1e9:.2f} GB over the {budget / 1e9:g} GB --max-job-memory")
    if j is None:
        srv.cancel(jid)
        problems.append("HANG: not final in time (cancelled)")
        res = "hang"
    else:
        stats = j.get("stats") or {}
        err = j.get("error") or {}
        res = f"{j['state']}"
        if j["state"] == "succeeded":
            res += f", denoised {stats.get('denoised')}, total {stats.get('total_ms', 0):.0f} ms, denoise {stats.get('denoise_ms', 0):.0f} ms"
            if stats.get("denoised") is not True:
                problems.append("SUCCEEDED WITH denoised false")
            fst, _, fb, _ = srv.req("GET", f"/v1/jobs/{jid}/frame", timeout=30)
            size = png_size(fb) if fst == 200 else None
            res += f", frame {fst} {size[0]}×{size[1]}" if size else f", frame {fst}"
            if size != (w, h):
                problems.append(f"frame {fst} size {size}")
        elif j["state"] == "failed" and err.get("code") == "denoise_failed":
            res += f" denoise_failed: {err.get('message', '')[:160]}"
        else:
            problems.append(f"{j['state']} {err.get('code')}: {err.get('message', '')[:200]}")
        res += f", wall {wall:.1f} s, {growth:+.0f} MB peak growth ({hwm / 1e9:.2f} GB resident at peak)"
    if not srv.healthy():
        problems.append("server not healthy")
        srv.restart()
    if "panicked" in srv.new_log():
        problems.append("panic in server log")
    row(area, tried, expected, res if not problems else "**DID NOT HOLD**: " + "; ".join(problems) + " — " + res,
        not problems, j)
    if j:
        srv.req("DELETE", f"/v1/jobs/{jid}", timeout=10)


def section_denoise(srv):
    for w, h in [(1, 1), (3, 2), (400, 1), (1024, 1024), (2048, 2048)]:
        for mode, spp in (("reference", 1), ("adaptive", 2)):
            if time_left() < 120:
                row("denoise", f"{mode} {w}×{h}", "", "skipped: out of time", False)
                continue
            denoise_case(srv, mode, w, h, spp)
    wide = Server("wide", ["--max-width", "100000", "--max-pixels", "100000"])
    try:
        for mode, spp in (("reference", 1), ("adaptive", 2)):
            if time_left() < 90:
                row("denoise", f"{mode} 100000×1", "", "skipped: out of time", False)
                continue
            denoise_case(wide, mode, 100000, 1, spp, area="denoise (--max-width 100000 --max-pixels 100000)")
    finally:
        wide.close()
    tight = Server("mem1.2", ["--max-job-memory", "1.2"])
    try:
        for mode, spp in (("reference", 1), ("adaptive", 2)):
            if time_left() < 90:
                row("denoise", f"{mode} 1024² at --max-job-memory 1.2", "", "skipped: out of time", False)
                continue
            denoise_case(tight, mode, 1024, 1024, spp, area="denoise (--max-job-memory 1.2)", budget=1.2e9)
    finally:
        tight.close()
    mem = Server("mem2", ["--max-job-memory", "2"])
    try:
        d = cornell()
        d["image"] = {"width": 4096, "height": 4096}
        d["render"].update(mode="adaptive", samples_per_pixel=2, denoise=True)
        mem.reset_hwm()
        rss0 = mem.status_kb("VmRSS")
        st, _, b, ms = mem.req("POST", "/v1/jobs", doc_bytes(d), {"Content-Type": JSON}, timeout=30)
        growth = (mem.status_kb("VmHWM") - rss0) * 1024 / MB
        j = json.loads(b) if b else {}
        err = j.get("error") or {}
        problems = []
        if st != 422 or err.get("code") != "over_limit":
            problems.append(f"answered {st} {err.get('code')}")
        if "--max-job-memory" not in err.get("message", ""):
            problems.append("message does not name --max-job-memory")
        if st == 201:
            mem.cancel(j["id"])
        res = f"{st} {err.get('code')} in {ms:.0f} ms, {growth:+.1f} MB: {err.get('message', '')[:220]}"
        row("denoise (--max-job-memory 2)", "adaptive 4096², 2 spp, render.denoise true",
            "422 over_limit naming --max-job-memory", res if not problems else "**DID NOT HOLD**: " + "; ".join(problems) + " — " + res,
            not problems, j)
    finally:
        mem.close()


# --------------------------------------------------------------------------- 4. command line


def section_cli(tmp):
    out = os.path.join(tmp, "out.png")
    cases = [
        ("--size 100000x100000", ["--size", "100000x100000"], "fail"),
        ("--spp 0", ["--spp", "0"], "fail"),
        ("--denoise --no-denoise", ["--denoise", "--no-denoise"], "fail"),
        ("--max-samples 0", ["--max-samples", "0"], "fail"),
        ("--mode adaptive --max-samples 1", ["--mode", "adaptive", "--max-samples", "1"], "fail"),
        ("--size 0x0", ["--size", "0x0"], "fail"),
        ("--size 16385x1", ["--size", "16385x1"], "fail"),
        ("--size -5x5", ["--size", "-5x5"], "fail"),
        ("--t0 nan", ["--t0", "nan"], "fail"),
        ("--max-time -1", ["--max-time", "-1"], "fail"),
        ("--max-pixels 0", ["--max-pixels", "0"], "fail"),
        ("--output out.txt", ["--output", os.path.join(tmp, "out.txt")], "fail"),
        ("a missing scene file", ["SCENE=/nonexistent/scene.json"], "fail"),
        ("a directory as the scene", ["SCENE=/tmp"], "fail"),
        ("a scene of 0xFF bytes", ["SCENE=" + os.path.join(tmp, "bad.json")], "fail"),
        ("--size 1x1 --spp 1 --denoise --mode reference (control)", ["--size", "1x1", "--spp", "1", "--denoise", "--mode", "reference"], "ok"),
    ]
    with open(os.path.join(tmp, "bad.json"), "wb") as f:
        f.write(b"\xff\xfe\x00garbage")

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (16 << 30, 16 << 30))  # an allocation bomb fails, not the machine

    for label, args, want in cases:
        scene = CORNELL
        rest = []
        for a in args:
            if a.startswith("SCENE="):
                scene = a[6:]
            else:
                rest.append(a)
        cmd = [BIN, "render", scene] + (["--output", out] if "--output" not in rest else []) + rest
        t0 = time.monotonic()
        try:
            p = subprocess.run(cmd, capture_output=True, timeout=120, preexec_fn=limit,
                               env={**os.environ, "RUST_BACKTRACE": "0"})
            rc, err = p.returncode, p.stderr.decode("utf-8", "replace")
        except subprocess.TimeoutExpired:
            rc, err = None, "timeout after 120 s"
        ms = (time.monotonic() - t0) * 1000
        lines = [l for l in err.splitlines() if l.strip()]
        first = lines[0] if lines else ""
        problems = []
        if want == "fail":
            if rc not in (1, 2):
                problems.append(f"exit {rc}" + (" (abort)" if rc in (134, -6) else ""))
            if "panicked" in err or "backtrace" in err.lower() or "RUST_BACKTRACE" in err:
                problems.append("panic/backtrace on stderr")
            if not first.startswith("error"):
                problems.append("first line is not an error sentence")
            extra = [l for l in lines[1:] if not l.strip().startswith(("Usage:", "For more information", "tip:"))]
            if extra:
                problems.append(f"{len(extra)} more lines besides the sentence and clap's usage hint")
        else:
            if rc != 0:
                problems.append(f"exit {rc}")
        res = f"exit {rc} in {ms:.0f} ms: {first[:230]}"
        row("cli", "glimpse render cornell-box.json " + label,
            "exit 1 or 2, one clear sentence, no backtrace" if want == "fail" else "exit 0",
            res if not problems else "**DID NOT HOLD**: " + "; ".join(problems) + " — " + res,
            not problems, dict(cmd=cmd, rc=rc, stderr=err[-2000:]))


# --------------------------------------------------------------------------- main


def cell(s):
    return str(s).replace("|", "\\|").replace("\n", " ")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="/tmp/probe")
    ap.add_argument("--only", default="uploads,cancel,denoise,cli")
    ap.add_argument("--match", default="", help="only the upload cases whose area or description contains this")
    a = ap.parse_args()
    global MATCH
    MATCH = a.match
    only = set(a.only.split(","))
    if not os.path.exists(BIN):
        sys.exit(f"{BIN} is missing: run `cargo build --release` first")
    os.makedirs(a.out, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix="glimpse-probe-cli-")
    started = time.monotonic()
    servers = []
    try:
        if "uploads" in only:
            section_uploads()
        if only & {"cancel", "denoise"}:
            main_srv = Server("main")
            servers.append(main_srv)
            if "cancel" in only:
                main_srv.new_log()
                section_cancel(main_srv)
            if "denoise" in only:
                section_denoise(main_srv)
        if "cli" in only:
            section_cli(tmp)
    finally:
        for s in servers:
            s.stop()
        shutil.rmtree(tmp, ignore_errors=True)
        for s in servers:
            shutil.rmtree(s.data, ignore_errors=True)
    held = sum(r["ok"] for r in ROWS)
    failed = len(ROWS) - held
    cases = sum(len(d["detail"]) if isinstance(d["detail"], list) else 1 for d in DETAILS)
    try:
        head = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        head = "?"
    built = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(os.path.getmtime(BIN)))
    lines = [f"# Glimpse hostile-input probe ({time.strftime('%Y-%m-%d %H:%M')}, {time.monotonic() - started:.0f} s)", "",
             f"Binary {BIN} built {built}, repository HEAD {head}.", "",
             f"{len(ROWS)} rows ({cases} cases): {held} held, {failed} did not hold. "
             "MB = 10^6 bytes of peak resident memory (VmHWM) growth over the case; ms = time to the answer.", "",
             "| area | tried | expected | result |", "|---|---|---|---|"]
    for r in ROWS:
        lines.append(f"| {cell(r['area'])} | {cell(r['tried'])} | {cell(r['expected'])} | {cell(r['result'])} |")
    table = "\n".join(lines) + "\n"
    with open(os.path.join(a.out, "table.md"), "w") as f:
        f.write(table)
    with open(os.path.join(a.out, "details.json"), "w") as f:
        json.dump(DETAILS, f, indent=1, default=str)
    print()
    print(table)
    print(f"table: {os.path.join(a.out, 'table.md')}, details: {os.path.join(a.out, 'details.json')}")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
