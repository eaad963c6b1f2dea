#!/usr/bin/env python3
"""Throughput of worker nodes: a batch of 8 jobs rendered by 1 worker, then by
2 workers, each on one render thread, against one API node that only serves, on the
PostgreSQL server scripts/pg.sh starts (or GLIMPSE_TEST_DATABASE_URL). Each run gets a
fresh database and job folder. The runs alternate (1, 2, 1, 2, ...) so that both see the
same machine; prints each batch's time (first submission to last finish) with the
load average of the minute before, and the ratio of the medians.

Usage: python3 scripts/cluster_throughput.py [--repeat 3] [--jobs 8] [--size 128] [--spp 96]
(needs `cargo build --release` first)"""

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
import uuid

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GLIMPSE = os.path.join(ROOT, "target", "release", "glimpse")
PSQL = "/usr/lib/postgresql/15/bin/psql"


def server_url():
    url = os.environ.get("GLIMPSE_TEST_DATABASE_URL", "").strip()
    if url:
        return url
    out = subprocess.run(["bash", os.path.join(ROOT, "scripts", "pg.sh"), "ensure"],
                         check=True, capture_output=True, text=True)
    return out.stdout.strip()


def fresh_database(server):
    name = "glimpse_tp_" + uuid.uuid4().hex
    subprocess.run([PSQL, server, "-q", "-c", f"CREATE DATABASE {name}"], check=True)
    return server.rsplit("/", 1)[0] + "/" + name


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def scene(k, size, spp):
    return {
        "version": 1, "name": f"tp-{k}",
        "image": {"width": size, "height": size},
        "camera": {"position": [0, 0, -4], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_y": 40},
        "materials": {
            "white": {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]},
            "floor": {"type": "diffuse", "texture": {"type": "checker", "scale": 0.5,
                                                      "a": [0.9, 0.9, 0.9], "b": [0.1, 0.1, 0.1]}},
        },
        "objects": [
            {"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "white"},
            {"type": "quad", "corner": [-5, -1, -5], "edge_u": [0, 0, 10], "edge_v": [10, 0, 0],
             "material": "floor"},
        ],
        "lights": [
            {"type": "point", "position": [2, 3, -2], "intensity": [20, 20, 20]},
            {"type": "environment", "radiance": [0.3, 0.3, 0.4]},
        ],
        "render": {"mode": "progressive", "samples_per_pixel": spp, "max_bounces": 2, "seed": k},
        "progressive": {"t0": 0.5, "initial_rate": 0.02},
    }


def http(method, url, body=None):
    data = json.dumps(body).encode() if body is not None else None
    req = urllib.request.Request(url, data=data, method=method,
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read() or b"null")


def batch(server, workers, jobs, size, spp):
    """Seconds from the first submission to the last job's end, with `workers` workers,
    and the jobs' mean render time (their `stats.total_ms`): when the second worker's
    batch is not twice as fast, this says whether its renders were slower (the cores
    were busy with other work) or the workers idle."""
    db = fresh_database(server)
    procs = []
    with tempfile.TemporaryDirectory() as data:
        try:
            port = free_port()
            base = f"http://127.0.0.1:{port}"
            quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
            procs.append(subprocess.Popen([GLIMPSE, "serve", "--addr", f"127.0.0.1:{port}",
                                           "--workers", "0", "--database", db, "--data", data],
                                          **quiet))
            for k in range(workers):
                procs.append(subprocess.Popen([GLIMPSE, "worker", "--database", db, "--data", data,
                                               "--threads", "1", "--name", f"w{k}"], **quiet))
            deadline = time.time() + 30
            while True:
                try:
                    http("GET", base + "/healthz")
                    break
                except OSError:
                    if time.time() > deadline:
                        sys.exit("the API node did not come up")
                    time.sleep(0.05)
            time.sleep(1.0)  # the workers connect and wait for work
            t0 = time.monotonic()
            ids = [http("POST", base + "/v1/jobs", scene(k + 1, size, spp))["id"] for k in range(jobs)]
            left = set(ids)
            render_ms = []
            while left:
                for i in list(left):
                    j = http("GET", f"{base}/v1/jobs/{i}")
                    if j["state"] == "succeeded":
                        left.discard(i)
                        render_ms.append(j["stats"]["total_ms"])
                    elif j["state"] in ("failed", "cancelled"):
                        sys.exit(f"job {i} ended {j['state']}: {j}")
                time.sleep(0.02)
            return time.monotonic() - t0, statistics.mean(render_ms) / 1e3
        finally:
            for p in procs:
                p.terminate()
            for p in procs:
                p.wait()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=8)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=96)
    a = ap.parse_args()
    server = server_url()
    times = {1: [], 2: []}
    for r in range(a.repeat):
        for w in (1, 2):
            t, per_job = batch(server, w, a.jobs, a.size, a.spp)
            times[w].append(t)
            load = os.getloadavg()[0]
            print(f"run {r + 1}: {w} worker(s), {a.jobs} jobs: {t:.2f} s "
                  f"(a job's render: {per_job:.2f} s on average; load average {load:.2f})",
                  flush=True)
    one, two = statistics.median(times[1]), statistics.median(times[2])
    print(f"median: 1 worker {one:.2f} s, 2 workers {two:.2f} s; ratio 2/1 = {two / one:.2f}")


if __name__ == "__main__":
    main()
