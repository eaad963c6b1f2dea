"""Peak resident memory of `glimpse serve` running one job, per mode, with and without the
denoiser, at the largest image the default limits accept (4096²): a fresh server per job,
its VmHWM read when the job ends (docs/measurements.md, "Memory of one job").

Usage, after `cargo build --release`: python3 scripts/job_memory.py [SIZE [SPP [MODE...]]]
"""
import json, os, socket, subprocess, sys, tempfile, time, urllib.error, urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target/release/glimpse")
size = int(sys.argv[1]) if len(sys.argv) > 1 else 4096
spp = int(sys.argv[2]) if len(sys.argv) > 2 else 2
modes = sys.argv[3:] or ["reference", "progressive", "guo", "adaptive"]
scene = json.load(open(os.path.join(ROOT, "scenes/cornell-box.json")))
# The loop runs whatever its paths cost, so that its own memory is measured.
scene.setdefault("progressive", {})["force_loop"] = True
scene["image"] = {"width": size, "height": size}
scene["render"]["samples_per_pixel"] = spp

def free_port():
    s = socket.socket(); s.bind(("127.0.0.1", 0)); p = s.getsockname()[1]; s.close(); return p

def hwm(pid):
    for l in open(f"/proc/{pid}/status"):
        if l.startswith("VmHWM:"):
            return int(l.split()[1]) * 1024

for mode in modes:
    for denoise in [False, True]:
        data = tempfile.mkdtemp()
        port = free_port()
        srv = subprocess.Popen([BIN, "serve", "--addr", f"127.0.0.1:{port}", "--data", data],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        base = f"http://127.0.0.1:{port}"
        for _ in range(200):
            try:
                urllib.request.urlopen(base + "/healthz"); break
            except Exception:
                time.sleep(0.05)
        s = dict(scene); s["render"] = dict(scene["render"], mode=mode, denoise=denoise)
        req = urllib.request.Request(base + "/v1/jobs", data=json.dumps(s).encode(),
                                     headers={"content-type": "application/json"})
        try:
            job = json.load(urllib.request.urlopen(req))
        except urllib.error.HTTPError as e:
            print(f"{mode:12s} denoise={denoise!s:5s} {size}²: refused {e.code} {json.load(e)['error']['message']}", flush=True)
            srv.kill(); continue
        t = time.time()
        while True:
            j = json.load(urllib.request.urlopen(f"{base}/v1/jobs/{job['id']}"))
            if j["state"] in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(0.2)
        peak = hwm(srv.pid)
        st = j.get("stats") or {}
        print(f"{mode:12s} denoise={denoise!s:5s} {size}²: {j['state']}, peak {peak/1e9:5.2f} GB, "
              f"{time.time()-t:6.1f} s, denoise {st.get('denoise_ms',0)/1e3:5.1f} s {j.get('error') or ''}", flush=True)
        srv.kill(); srv.wait()
