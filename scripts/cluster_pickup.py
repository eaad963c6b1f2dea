#!/usr/bin/env python3
"""Pickup latency across nodes (LISTEN/NOTIFY): jobs submitted one at a time
to an API node that only serves (--workers 0) and claimed by an idle worker node, on the
PostgreSQL server scripts/pg.sh starts (or GLIMPSE_TEST_DATABASE_URL). A job's pickup
is its `started_at` (the worker's claim) minus its `created_at` (the API node's insert),
both on this machine's clock. Each binary named runs with a fresh database, alternating,
so the two see the same machine; prints each run's median and the load average.

Usage: python3 scripts/cluster_pickup.py [--jobs 20] [--repeat 2] [BINARY ...]
(default binary: target/release/glimpse; name an older build to compare)"""

import argparse
import datetime
import os
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from cluster_throughput import GLIMPSE, free_port, fresh_database, http, scene, server_url  # noqa: E402


def when(s):
    return datetime.datetime.strptime(s, "%Y-%m-%dT%H:%M:%S.%fZ")


def pickups(binary, server, jobs):
    """Milliseconds from insert to claim of `jobs` jobs submitted one after another."""
    db = fresh_database(server)
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    procs = []
    with tempfile.TemporaryDirectory() as data:
        try:
            port = free_port()
            base = f"http://127.0.0.1:{port}"
            procs.append(subprocess.Popen([binary, "serve", "--addr", f"127.0.0.1:{port}",
                                           "--workers", "0", "--database", db, "--data", data],
                                          **quiet))
            procs.append(subprocess.Popen([binary, "worker", "--database", db, "--data", data,
                                           "--threads", "1", "--name", "w"], **quiet))
            deadline = time.time() + 30
            while True:
                try:
                    http("GET", base + "/healthz")
                    break
                except OSError:
                    if time.time() > deadline:
                        sys.exit("the API node did not come up")
                    time.sleep(0.05)
            time.sleep(1.0)  # the worker connects and waits for work
            out = []
            for k in range(jobs):
                i = http("POST", base + "/v1/jobs", scene(k + 1, 16, 2))["id"]
                while True:
                    j = http("GET", f"{base}/v1/jobs/{i}")
                    if j["state"] in ("succeeded", "failed", "cancelled"):
                        break
                    time.sleep(0.01)
                out.append((when(j["started_at"]) - when(j["created_at"])).total_seconds() * 1e3)
                # Not in step with the worker's poll: a pause of its own length.
                time.sleep(0.037 * (k % 7))
            return out
        finally:
            for p in procs:
                p.terminate()
            for p in procs:
                p.wait()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("binaries", nargs="*", default=[GLIMPSE])
    a = ap.parse_args()
    server = server_url()
    all_ms = {b: [] for b in a.binaries}
    for r in range(a.repeat):
        for b in a.binaries:
            ms = pickups(b, server, a.jobs)
            all_ms[b] += ms
            load = os.getloadavg()[0]
            print(f"run {r + 1} {b}: pickup median {statistics.median(ms):.1f} ms "
                  f"(min {min(ms):.0f}, max {max(ms):.0f}; load average {load:.2f})", flush=True)
    for b, ms in all_ms.items():
        print(f"{b}: median {statistics.median(ms):.1f} ms over {len(ms)} jobs")


if __name__ == "__main__":
    main()
