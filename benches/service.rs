//! Service benchmark. Not a test: run it in release and read the numbers.
//!
//! ```text
//! cargo bench --bench service            # defaults: 512², 9 runs
//! GLIMPSE_BENCH_RUNS=9 cargo bench --bench service
//! ```
//!
//! Measures, on an idle in-process server (`glimpse::service::run` on 127.0.0.1:0):
//! 1. latency: wall time from sending `POST /v1/jobs` to receiving the PNG of the first
//!    frame on the job's WebSocket, for a 512² progressive scene (target < 250 ms);
//! 2. overhead: wall time of the same job through the service (POST → `done` on the
//!    stream, with the stream watching every frame) against `progressive::render` called
//!    directly on the same scene in the same process, alternating the two, medians
//!    compared (target < 5 %). The overhead covers HTTP, validation, the store, PNG
//!    encoding of the frames, the final files and the streaming.
//!
//! Like with like: both sides parse the same document under the same limits, build the
//! same `PathTracer` and call `progressive::render` with `RenderOptions::default()` on
//! rayon's global pool (the service's worker thread uses it too: no pool of its own).
//! Each run is preceded by 150 ms of idleness, so the service's work after a `done` (the
//! secondary layers and the EXR, written after it) never lands in the next direct run.
//! The render's own `total_ms` is printed for both sides: the gap between them is what
//! the service's concurrent work (frame encoding, streaming) costs the render itself.

use futures_util::StreamExt;
use glimpse::progressive::{self, RenderOptions};
use glimpse::scene::{parse_scene, SceneOrigin};
use glimpse::tracer::PathTracer;
use serde_json::{json, Value};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

fn scene(size: u32) -> Value {
    json!({
        "version": 1, "name": "bench",
        "image": { "width": size, "height": size },
        "camera": { "position": [0, 0.5, -5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_y": 40 },
        "materials": {
            "white": { "type": "diffuse", "albedo": [0.8, 0.8, 0.8] },
            "red": { "type": "diffuse", "albedo": [0.7, 0.1, 0.1] },
            "floor": { "type": "diffuse", "texture": { "type": "checker", "scale": 0.5,
                       "a": [0.9, 0.9, 0.9], "b": [0.1, 0.1, 0.1] } }
        },
        "objects": [
            { "type": "sphere", "center": [-0.8, 0, 0], "radius": 1, "material": "white" },
            { "type": "sphere", "center": [1.2, -0.4, -0.5], "radius": 0.6, "material": "red" },
            { "type": "quad", "corner": [-6, -1, -6], "edge_u": [0, 0, 12], "edge_v": [12, 0, 0],
              "material": "floor" }
        ],
        "lights": [
            { "type": "point", "position": [2, 4, -3], "intensity": [30, 30, 30] },
            { "type": "environment", "radiance": [0.3, 0.3, 0.4] }
        ],
        "render": { "mode": "progressive", "samples_per_pixel": 16, "max_bounces": 3, "seed": 1 }
    })
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn submit(c: &reqwest::Client, base: &str, doc: &Value) -> String {
    let r = c
        .post(format!("{base}/v1/jobs"))
        .json(doc)
        .send()
        .await
        .expect("post");
    assert_eq!(r.status(), 201);
    r.json::<Value>().await.expect("json")["id"]
        .as_str()
        .expect("id")
        .to_owned()
}

async fn connect(addr: std::net::SocketAddr, id: &str) -> Ws {
    tokio_tungstenite::connect_async(format!("ws://{addr}/v1/jobs/{id}/stream"))
        .await
        .expect("ws")
        .0
}

/// Reads until the first binary (PNG) message; returns its arrival time.
async fn first_png(ws: &mut Ws) -> Instant {
    while let Some(m) = ws.next().await {
        if let Ok(Message::Binary(_)) = m {
            return Instant::now();
        }
    }
    panic!("stream ended before a frame");
}

/// Reads until `done`; returns (arrival time, frames received, job stats total_ms).
async fn until_done(ws: &mut Ws) -> (Instant, usize, f64) {
    let mut frames = 0;
    while let Some(m) = ws.next().await {
        match m {
            Ok(Message::Binary(_)) => frames += 1,
            Ok(Message::Text(t)) => {
                let v: Value = serde_json::from_str(&t).expect("json");
                if v["type"] == "done" {
                    let total = v["job"]["stats"]["total_ms"].as_f64().unwrap_or(f64::NAN);
                    return (Instant::now(), frames, total);
                }
                assert_ne!(v["type"], "error", "{v}");
            }
            _ => {}
        }
    }
    panic!("stream ended before done");
}

fn main() {
    let runs: usize = std::env::var("GLIMPSE_BENCH_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(9);
    let size: u32 = std::env::var("GLIMPSE_BENCH_SIZE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(512);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async move {
        let dir = tempfile::tempdir().expect("tempdir");
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let server = tokio::spawn(glimpse::service::run(listener, glimpse::service::Config::new(dir.path()), async {
            let _ = stop_rx.await;
        }));
        let base = format!("http://{addr}");
        let c = reqwest::Client::new();
        while c.get(format!("{base}/healthz")).send().await.is_err() {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        let doc = scene(size);
        let text = doc.to_string();

        // Warm-up (page cache, rayon pool, first-use allocations).
        let id = submit(&c, &base, &doc).await;
        let mut ws = connect(addr, &id).await;
        until_done(&mut ws).await;

        // 1. POST → first frame. The stream is opened right after the 201, as a client would.
        let mut latency = Vec::new();
        for _ in 0..runs {
            let t0 = Instant::now();
            let id = submit(&c, &base, &doc).await;
            let mut ws = connect(addr, &id).await;
            let t1 = first_png(&mut ws).await;
            latency.push((t1 - t0).as_secs_f64() * 1e3);
            let _ = c.post(format!("{base}/v1/jobs/{id}/cancel")).send().await;
            let _ = until_done(&mut ws).await;
        }

        // 2. Through the service vs direct, alternating so drift hits both alike.
        let mut direct = Vec::new();
        let mut served = Vec::new();
        let mut frames_seen = 0;
        let mut job_total = Vec::new();
        let mut direct_total = Vec::new();
        for _ in 0..runs {
            // An idle moment before each pair: the service writes a job's secondary files
            // (other layers, EXR) after its `done`, and that work must not land inside the
            // next direct run (it would slow the direct render and flatter the service).
            tokio::time::sleep(Duration::from_millis(150)).await;
            let text2 = text.clone();
            let d = tokio::task::spawn_blocking(move || {
                let t0 = Instant::now();
                let sc = parse_scene(&text2, &SceneOrigin::Request, &glimpse::service::server_limits()).expect("scene");
                let tracer = PathTracer::new(&sc);
                let cancel = glimpse::cancel::CancelToken::new();
                let f = progressive::render(&sc, &tracer, &RenderOptions::default(), &mut |_| {}, &cancel)
                    .expect("render");
                (t0.elapsed().as_secs_f64() * 1e3, f.stats.total_ms)
            })
            .await
            .expect("join");
            direct.push(d.0);
            tokio::time::sleep(Duration::from_millis(150)).await;
            let t0 = Instant::now();
            let id = submit(&c, &base, &doc).await;
            let mut ws = connect(addr, &id).await;
            let (t1, frames, total) = until_done(&mut ws).await;
            served.push((t1 - t0).as_secs_f64() * 1e3);
            // An idle moment after it too: the work the service does after `done` (the
            // secondary files) must finish before the next direct run starts.
            drop(ws);
            tokio::time::sleep(Duration::from_millis(150)).await;
            frames_seen = frames;
            job_total.push(total);
            direct_total.push(d.1);
        }
        let (md, ms) = (median(direct.clone()), median(served.clone()));
        println!("glimpse service bench: {size}x{size} progressive, spp 16, {runs} runs, 1 worker");
        println!(
            "POST -> first frame on the stream: median {:.1} ms, min {:.1} ms, max {:.1} ms (target < 250 ms)",
            median(latency.clone()),
            latency.iter().copied().fold(f64::INFINITY, f64::min),
            latency.iter().copied().fold(0.0, f64::max)
        );
        println!(
            "render direct (progressive::render): median {md:.1} ms  {:?}",
            direct.iter().map(|v| v.round()).collect::<Vec<_>>()
        );
        println!(
            "through the service (POST -> done, streaming every frame): median {ms:.1} ms  {:?}; last job streamed {frames_seen} frames; job total_ms median {:.1}",
            served.iter().map(|v| v.round()).collect::<Vec<_>>(),
            median(job_total.clone())
        );
        println!(
            "render's own total_ms (progressive stats): direct median {:.1}, in the service {:.1} (what the service's concurrent work costs the render itself)",
            median(direct_total.clone()),
            median(job_total.clone())
        );
        // Per service run, its wall time minus its own render's total_ms: what the service
        // adds outside the render (HTTP, store, files, streaming) — the same job on both
        // sides of the subtraction, so the render's run-to-run noise cancels.
        let outside = median(served.iter().zip(&job_total).map(|(s, t)| s - t).collect());
        println!("outside the render (POST -> done minus the job's own total_ms): median {outside:.1} ms");
        println!("service overhead: {:+.2} % of render time, ratio of medians (target < 5 %)", (ms - md) / md * 100.0);
        // Each service run follows its direct run: the median of the per-pair ratios
        // cancels the machine's drift better than the ratio of the two medians.
        let paired = median(served.iter().zip(&direct).map(|(s, d)| (s - d) / d * 100.0).collect());
        println!("service overhead: {paired:+.2} %, median of the {runs} paired runs (target < 5 %)");
        let _ = stop_tx.send(());
        let _ = server.await;
    });
}
