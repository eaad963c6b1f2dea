#!/usr/bin/env python3
"""Random requests against a live `glimpse serve`: the server must answer every one with a
status below 500, never serve one of its own files, and stay up.

    cargo build --release && python3 scripts/fuzz_service.py [--seed 1] [--requests 600]

It starts the release binary on a free loopback port with a throwaway data folder and
sends a mix of: job submissions built from the bundled scenes with odd sizes, sample
counts, objects and OBJ paths (some truncated, some with odd content types); random bytes
with every method; and GET/DELETE/POST/HEAD/OPTIONS on every route with unknown, huge and
traversal-shaped job ids and query values. Standard library only.
"""
import argparse
import http.client
import json
import os
import random
import shutil
import socket
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--requests", type=int, default=600)
    ap.add_argument("--binary", default=os.path.join(ROOT, "target/release/glimpse"))
    a = ap.parse_args()
    rng = random.Random(a.seed)
    port = free_port()
    data = tempfile.mkdtemp(prefix="glimpse-fuzz-")
    log = open(os.path.join(data, "server.log"), "w")
    srv = subprocess.Popen(
        [a.binary, "serve", "--addr", f"127.0.0.1:{port}", "--data", os.path.join(data, "d")],
        stdout=subprocess.DEVNULL,
        stderr=log,
    )
    for _ in range(100):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            break
        except OSError:
            time.sleep(0.05)
    scenes_dir = os.path.join(ROOT, "scenes")
    scenes = [
        json.load(open(os.path.join(scenes_dir, f)))
        for f in sorted(os.listdir(scenes_dir))
        if f.endswith(".json")
    ]
    own_files = [b"[package]", b"root:x:0", b"CREATE TABLE"]

    def req(method, path, body=None, headers=None):
        c = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
        try:
            c.request(method, path, body=body, headers=headers or {})
            r = c.getresponse()
            return r.status, r.read()
        finally:
            c.close()

    routes = [
        "/v1/jobs", "/v1/jobs/{id}", "/v1/jobs/{id}/cancel", "/v1/jobs/{id}/frame",
        "/v1/jobs/{id}/stream", "/v1/examples", "/", "/healthz", "/metrics",
        "/v1/jobs/../../etc/passwd", "/v1/jobs/%2e%2e%2f%2e%2e%2fetc%2fpasswd",
        "/v1/jobs/{id}/frame?layer=../../x", "/v1/jobs/{id}/frame?iteration=-1",
        "/v1/jobs/{id}/frame?iteration=99999999999999999999",
        "/v1/jobs/{id}/frame?layer=distance&format=exr", "/v1/jobs?limit=0",
        "/v1/jobs?limit=99999999999", "/v1/jobs?cursor=%00", "/static/../Cargo.toml",
        "/viewer/../../Cargo.toml", "/%2e%2e/Cargo.toml", "/glimpse.db",
    ]
    ids, bad = [], 0
    for _ in range(a.requests):
        r = rng.random()
        try:
            if r < 0.4:
                d = json.loads(json.dumps(rng.choice(scenes)))
                d["image"] = {"width": rng.choice([8, 16, 1, 0, 5000, -3, "x"]),
                              "height": rng.choice([8, 6, 1])}
                d["render"]["samples_per_pixel"] = rng.choice([1, 2, 0, 99999])
                if rng.random() < 0.3:
                    d["objects"] = rng.choice([[], None, [{}], "x"])
                if rng.random() < 0.2 and isinstance(d.get("objects"), list):
                    d["objects"][0:1] = [{"type": "obj", "material": "white",
                                          "path": rng.choice(["/etc/passwd", "../../Cargo.toml", "x.obj"])}]
                body = json.dumps(d)
                if rng.random() < 0.2:
                    body = body[: rng.randint(0, len(body))]
                ct = rng.choice(["application/json", "text/plain",
                                 "application/x-www-form-urlencoded", ""])
                st, b = req("POST", "/v1/jobs", body.encode(), {"Content-Type": ct})
                if st in (200, 201, 202):
                    try:
                        ids.append(json.loads(b)["id"])
                    except (ValueError, KeyError, TypeError):
                        pass
            elif r < 0.5:
                st, b = req(rng.choice(["POST", "PUT", "PATCH", "DELETE"]),
                            rng.choice(["/v1/jobs", "/v1/jobs/abc", "/"]),
                            os.urandom(rng.randint(0, 4000)), {"Content-Type": "application/json"})
            else:
                jid = rng.choice(ids + ["nonexistent", "0", "a" * 300, "%00", "..", "-1"])
                path = rng.choice(routes).replace("{id}", jid)
                st, b = req(rng.choice(["GET", "GET", "DELETE", "POST", "HEAD", "OPTIONS"]), path)
            if st >= 500:
                bad += 1
                print("5xx", st, b[:200])
            if any(m in b for m in own_files):
                bad += 1
                print("served one of its own files:", b[:100])
        except (OSError, http.client.HTTPException) as e:
            if srv.poll() is not None:
                print("server died:", e)
                bad += 1
                break
            print("request failed:", type(e).__name__, e)
    alive = srv.poll() is None
    srv.terminate()
    srv.wait(timeout=30)
    log.close()
    panics = open(os.path.join(data, "server.log")).read().count("panicked")
    shutil.rmtree(data, ignore_errors=True)
    print(f"{a.requests} requests, {len(ids)} jobs accepted, {bad} problems, "
          f"server alive: {alive}, panics logged: {panics}")
    sys.exit(0 if bad == 0 and alive and panics == 0 else 1)


if __name__ == "__main__":
    main()
