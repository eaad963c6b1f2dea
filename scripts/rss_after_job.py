#!/usr/bin/env python3
"""Resident memory of the server before, during and after one 4096x4096 job.

Usage: python3 scripts/rss_after_job.py [--progressive] [BINARY ...]
       (default target/release/glimpse; reference mode unless --progressive)

For each binary in turn (side by side, one run): start `serve` on a free loopback port
with a fresh data folder, read VmRSS, submit a 4096x4096 reference job (1 spp, one
bounce), sample the peak while it runs, then VmRSS 2 s and 15 s after it succeeded.
"""
import json, os, shutil, socket, subprocess, sys, tempfile, time, urllib.request

def rss_kib(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS"):
                return int(line.split()[1])

def free_port():
    s = socket.socket(); s.bind(("127.0.0.1", 0)); p = s.getsockname()[1]; s.close(); return p

def call(method, url, body=None):
    req = urllib.request.Request(url, data=body, method=method,
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req) as r:
        return json.load(r)

def measure(binary):
    data = tempfile.mkdtemp()
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    p = subprocess.Popen([binary, "serve", "--addr", f"127.0.0.1:{port}", "--data", data],
                         stderr=subprocess.DEVNULL, env={**os.environ, "RUST_LOG": "warn"})
    try:
        for _ in range(400):
            try:
                call("GET", base + "/healthz"); break
            except Exception:
                time.sleep(0.05)
        idle = rss_kib(p.pid)
        scene = {"version": 1, "name": "big", "image": {"width": 4096, "height": 4096},
                 "camera": {"position": [0, 0, -4], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_y": 40},
                 "materials": {"white": {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]}},
                 "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "white"}],
                 "lights": [{"type": "point", "position": [2, 3, -2], "intensity": [20, 20, 20]},
                            {"type": "environment", "radiance": [0.3, 0.3, 0.4]}],
                 "render": {"mode": MODE, "samples_per_pixel": 1, "max_bounces": 1, "seed": 1}}
        job = call("POST", base + "/v1/jobs", json.dumps(scene).encode())
        peak = 0
        while True:
            peak = max(peak, rss_kib(p.pid))
            state = call("GET", f"{base}/v1/jobs/{job['id']}")["state"]
            if state in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(0.05)
        t = time.time()
        while time.time() < t + 2:
            peak = max(peak, rss_kib(p.pid)); time.sleep(0.05)
        after2 = rss_kib(p.pid)
        while time.time() < t + 15:
            peak = max(peak, rss_kib(p.pid)); time.sleep(0.05)
        after15 = rss_kib(p.pid)
        print(f"{binary}: {state}; RSS idle {idle // 1024} MiB, peak {peak // 1024} MiB, "
              f"2 s after {after2 // 1024} MiB, 15 s after {after15 // 1024} MiB", flush=True)
    finally:
        p.terminate(); p.wait()
        shutil.rmtree(data, ignore_errors=True)

args = sys.argv[1:]
MODE = "progressive" if "--progressive" in args else "reference"
args = [a for a in args if a != "--progressive"]
for b in args or ["target/release/glimpse"]:
    measure(b)
