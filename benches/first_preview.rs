//! How soon a submitted job shows its first picture, as a user of the service sees it.
//!
//! Starts the real `glimpse serve` (the release binary, embedded store, one worker) on
//! loopback, then for the Cornell box (`scenes/cornell-box.json`, resized) at 320×240,
//! 1024×768 and 2048² times, from the moment the `POST /v1/jobs` is sent:
//! - the first binary message (the PNG of the first frame) on the job's WebSocket stream,
//!   opened right after the 201 as the viewer does;
//! - the first `200` of `GET /v1/jobs/{id}/frame`, polled every 5 ms beside the stream.
//!
//! Each job is cancelled at its first frame and deleted (which waits for the files written
//! after its end) before the next, so runs do not overlap: the server is idle at each POST. One warm-up job first (page cache, the worker's thread pool). Medians
//! of `GLIMPSE_BENCH_RUNS` (default 7) per size, printed with pass/fail against the
//! target of 300 ms (a first preview within 300 ms of the POST at any accepted size).
//!
//! Run: `cargo bench --bench first_preview` (under a minute once built).

use futures_util::StreamExt;
use serde_json::Value;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

const TARGET_MS: f64 = 300.0;
const SIZES: [(u32, u32); 3] = [(320, 240), (1024, 768), (2048, 2048)];

/// The server process, killed when the bench ends (or panics).
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

fn cornell_box(w: u32, h: u32) -> String {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cornell-box.json");
    let text = std::fs::read_to_string(path).expect("scenes/cornell-box.json");
    let mut doc: Value = serde_json::from_str(&text).expect("the Cornell box is JSON");
    doc["image"]["width"] = w.into();
    doc["image"]["height"] = h.into();
    doc.to_string()
}

async fn start(data: &std::path::Path, c: &reqwest::Client) -> (Server, String) {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let bin = std::env::var_os("GLIMPSE_BENCH_BIN")
        .unwrap_or_else(|| env!("CARGO_BIN_EXE_glimpse").into());
    let child = Command::new(bin)
        .args(["serve", "--addr", &format!("127.0.0.1:{port}"), "--data"])
        .arg(data)
        .env_remove("GLIMPSE_TOKEN")
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .spawn()
        .expect("glimpse serve");
    let server = Server(child);
    let base = format!("http://127.0.0.1:{port}");
    let deadline = Instant::now() + Duration::from_secs(20);
    while c.get(format!("{base}/healthz")).send().await.is_err() {
        assert!(Instant::now() < deadline, "the server did not come up");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    (server, base)
}

/// Polls the job's frame until it is served; the time of the `200`.
async fn first_get(c: reqwest::Client, url: String) -> Instant {
    loop {
        if let Ok(r) = c.get(&url).send().await {
            if r.status() == 200 && r.bytes().await.is_ok() {
                return Instant::now();
            }
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

/// One job: (POST → first frame on the stream, POST → first frame over GET), in ms.
async fn one(c: &reqwest::Client, base: &str, body: &str) -> (f64, f64) {
    let t0 = Instant::now();
    let r = c
        .post(format!("{base}/v1/jobs"))
        .header("content-type", "application/json")
        .body(body.to_owned())
        .send()
        .await
        .expect("post");
    assert_eq!(r.status(), 201, "{}", r.text().await.unwrap_or_default());
    let job: Value = r.json().await.expect("json");
    let id = job["id"].as_str().expect("id").to_owned();
    let get = tokio::spawn(first_get(c.clone(), format!("{base}/v1/jobs/{id}/frame")));
    let ws_url = format!("{}/v1/jobs/{id}/stream", base.replacen("http", "ws", 1));
    let (mut ws, _) = tokio_tungstenite::connect_async(ws_url)
        .await
        .expect("stream");
    let mut t_ws = None;
    while let Some(m) = ws.next().await {
        if let Ok(Message::Binary(_)) = m {
            t_ws = Some(Instant::now());
            break;
        }
    }
    let t_ws = t_ws.expect("a frame before the stream ended");
    let t_get = get.await.expect("poller");
    let _ = c.post(format!("{base}/v1/jobs/{id}/cancel")).send().await;
    // Until `done`: the next job must not share the machine with this one.
    while let Some(Ok(m)) = ws.next().await {
        if matches!(m, Message::Close(_)) {
            break;
        }
    }
    // DELETE waits for the writes that follow `done` (the cancelled job's last frame and
    // its layers): the worker is idle again once it answers.
    let r = c.delete(format!("{base}/v1/jobs/{id}")).send().await;
    assert!(r.is_ok_and(|r| r.status().is_success()), "delete");
    tokio::time::sleep(Duration::from_millis(100)).await;
    let ms = |t: Instant| (t - t0).as_secs_f64() * 1e3;
    (ms(t_ws), ms(t_get))
}

fn main() {
    let runs: usize = std::env::var("GLIMPSE_BENCH_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(7);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async move {
        let data = tempfile::tempdir().expect("tempdir");
        let c = reqwest::Client::new();
        let (_server, base) = start(data.path(), &c).await;
        one(&c, &base, &cornell_box(320, 240)).await;
        println!(
            "POST -> first frame, the Cornell box, real server, median of {runs} (target ≤ {TARGET_MS:.0} ms):"
        );
        let mut all_pass = true;
        for (w, h) in SIZES {
            let body = cornell_box(w, h);
            let (mut ws, mut get) = (Vec::new(), Vec::new());
            for _ in 0..runs {
                let (a, b) = one(&c, &base, &body).await;
                ws.push(a);
                get.push(b);
            }
            let (mw, mg) = (median(ws.clone()), median(get.clone()));
            let pass = mw <= TARGET_MS && mg <= TARGET_MS;
            all_pass &= pass;
            println!(
                "  {w}x{h}: stream {mw:.0} ms, GET {mg:.0} ms  {}   (stream {:?})",
                if pass { "pass" } else { "FAIL" },
                ws.iter().map(|v| v.round()).collect::<Vec<_>>()
            );
        }
        println!("{}", if all_pass { "all sizes pass" } else { "some size fails" });
    });
}
