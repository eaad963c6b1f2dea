//! The service end to end (service-api.md): the real server on a loopback port
//! (`glimpse::service::run` in this process), a real HTTP client and a real WebSocket
//! client. Scenes are tiny so each test takes a second or two in the dev profile.

mod common;

use futures_util::{SinkExt, StreamExt};
use serde_json::{json, Value};
use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

struct Server {
    addr: SocketAddr,
    client: reqwest::Client,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    task: Option<tokio::task::JoinHandle<anyhow::Result<()>>>,
    _dir: Option<tempfile::TempDir>,
}

impl Server {
    async fn start(tweak: impl FnOnce(&mut glimpse::service::Config)) -> Self {
        let dir = tempfile::tempdir().unwrap();
        let mut s = Self::start_in(dir.path(), tweak).await;
        s._dir = Some(dir);
        s
    }

    async fn start_in(dir: &Path, tweak: impl FnOnce(&mut glimpse::service::Config)) -> Self {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let mut config = glimpse::service::Config::new(dir);
        config.database = common::test_database(dir).await;
        tweak(&mut config);
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn(glimpse::service::run(listener, config, async {
            let _ = rx.await;
        }));
        let client = reqwest::Client::new();
        let s = Self {
            addr,
            client,
            stop: Some(tx),
            task: Some(task),
            _dir: None,
        };
        // Ready once /healthz answers.
        let deadline = Instant::now() + Duration::from_secs(10);
        while s.client.get(s.url("/healthz")).send().await.is_err() {
            assert!(Instant::now() < deadline, "server did not come up");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        s
    }

    /// Graceful stop; returns what `run` returned.
    async fn stop(mut self) -> anyhow::Result<()> {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        let task = self.task.take().unwrap();
        tokio::time::timeout(Duration::from_secs(10), task)
            .await
            .expect("shutdown took > 10 s")
            .unwrap()
    }

    fn url(&self, p: &str) -> String {
        format!("http://{}{p}", self.addr)
    }

    async fn post_scene(&self, scene: &Value) -> reqwest::Response {
        self.client
            .post(self.url("/v1/jobs"))
            .json(scene)
            .send()
            .await
            .unwrap()
    }

    async fn submit(&self, scene: &Value) -> String {
        let r = self.post_scene(scene).await;
        assert_eq!(r.status(), 201, "{:?}", r.text().await);
        let loc = r.headers()["location"].to_str().unwrap().to_owned();
        let job: Value = r.json().await.unwrap();
        let id = job["id"].as_str().unwrap().to_owned();
        assert_eq!(loc, format!("/v1/jobs/{id}"));
        assert_eq!(job["state"], "queued");
        id
    }

    /// `GET` of a path on this server.
    async fn get(&self, path: &str) -> reqwest::Response {
        self.client.get(self.url(path)).send().await.unwrap()
    }

    /// `DELETE` of a path on this server.
    async fn delete(&self, path: &str) -> reqwest::Response {
        self.client.delete(self.url(path)).send().await.unwrap()
    }

    /// `POST /v1/jobs/{id}/cancel`.
    async fn cancel(&self, id: &str) -> reqwest::Response {
        self.client
            .post(self.url(&format!("/v1/jobs/{id}/cancel")))
            .send()
            .await
            .unwrap()
    }

    async fn job(&self, id: &str) -> Value {
        let r = self.get(&format!("/v1/jobs/{id}")).await;
        assert_eq!(r.status(), 200);
        r.json().await.unwrap()
    }

    /// Polls until the job is in one of `states`.
    async fn wait_state(&self, id: &str, states: &[&str], within: Duration) -> Value {
        let base = format!("http://{}", self.addr);
        common::wait_states(&self.client, &base, id, states, within).await
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
    }
}

/// A small valid scene (common::sphere_scene).
fn scene(w: u32, h: u32, mode: &str, spp: u32) -> Value {
    common::sphere_scene("tiny", w, h, mode, spp, 1)
}

/// A reference render big enough to keep a worker busy for a while.
fn long_scene() -> Value {
    scene(512, 512, "reference", 512)
}

async fn error_of(r: reqwest::Response, status: u16, code: &str) -> Value {
    assert_eq!(r.status(), status);
    let b: Value = r.json().await.unwrap();
    assert_eq!(b["error"]["code"], code, "{b}");
    assert!(
        b["error"]["message"]
            .as_str()
            .is_some_and(|m| !m.is_empty()),
        "{b}"
    );
    assert!(b["error"].get("path").is_some(), "{b}");
    b
}

fn is_png(b: &[u8]) -> bool {
    b.starts_with(b"\x89PNG\r\n\x1a\n")
}

fn png_size(b: &[u8]) -> (u32, u32) {
    let img = image::load_from_memory(b).unwrap();
    (img.width(), img.height())
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn ws_connect(s: &Server, id: &str, token: Option<&str>) -> Ws {
    let q = token.map(|t| format!("?token={t}")).unwrap_or_default();
    let (ws, _) =
        tokio_tungstenite::connect_async(format!("ws://{}/v1/jobs/{id}/stream{q}", s.addr))
            .await
            .unwrap();
    ws
}

/// Reads the whole stream: (text messages, PNG payloads), checking that every `frame`
/// text is followed by exactly one binary message.
async fn read_stream(ws: &mut Ws, within: Duration) -> (Vec<Value>, Vec<Vec<u8>>) {
    let (mut texts, mut pngs) = (Vec::new(), Vec::new());
    let mut expect_binary = false;
    let deadline = tokio::time::Instant::now() + within;
    loop {
        let m = tokio::time::timeout_at(deadline, ws.next())
            .await
            .expect("stream did not end in time");
        match m {
            Some(Ok(Message::Text(t))) => {
                assert!(!expect_binary, "a frame text must be followed by its PNG");
                let v: Value = serde_json::from_str(&t).unwrap();
                expect_binary = v["type"] == "frame";
                texts.push(v);
            }
            Some(Ok(Message::Binary(b))) => {
                assert!(expect_binary, "binary without a frame message");
                expect_binary = false;
                pngs.push(b.to_vec());
            }
            Some(Ok(Message::Close(_))) | None => break,
            Some(Ok(_)) => {}
            Some(Err(e)) => panic!("websocket error: {e}"),
        }
    }
    (texts, pngs)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn submit_stream_frames_layers_exr_list_delete() {
    let s = Server::start(|_| {}).await;
    // Hold the only worker with a long job so the streamed job is queued when we connect:
    // the stream then sees every frame from the first.
    let blocker = s.submit(&long_scene()).await;
    let sc = scene(48, 48, "progressive", 8);
    let id = s.submit(&sc).await;
    let mut ws = ws_connect(&s, &id, None).await;
    let first = tokio::time::timeout(Duration::from_secs(5), ws.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    let first: Value = serde_json::from_str(first.to_text().unwrap()).unwrap();
    assert_eq!(first["type"], "state");
    assert_eq!(first["job"]["id"], id.as_str());
    assert_eq!(first["job"]["state"], "queued");
    let r = s.cancel(&blocker).await;
    assert_eq!(r.status(), 202);

    let (texts, pngs) = read_stream(&mut ws, Duration::from_secs(60)).await;
    let frames: Vec<&Value> = texts.iter().filter(|t| t["type"] == "frame").collect();
    assert!(
        frames.len() >= 2,
        "expected at least 2 frames, got {texts:?}"
    );
    assert_eq!(pngs.len(), frames.len());
    let iters: Vec<u64> = frames
        .iter()
        .map(|f| f["iteration"].as_u64().unwrap())
        .collect();
    assert!(
        iters.windows(2).all(|w| w[0] < w[1]),
        "iterations must increase: {iters:?}"
    );
    for f in &frames {
        assert!(
            f["layers"].as_array().unwrap().iter().any(|l| l == "image"),
            "{f}"
        );
        let p = &f["progress"];
        assert!(p["pixels_traced"].as_u64().unwrap() > 0, "{p}");
        let frac = p["pixel_fraction"].as_f64().unwrap();
        assert!(frac > 0.0 && frac <= 1.0, "{p}");
        assert!(
            p.get("eta_ms").is_some() && p.get("elapsed_ms").is_some(),
            "{p}"
        );
    }
    for f in &frames {
        // Each frame says the size of its PNG and of the image (the same below a preview's
        // size).
        assert_eq!(
            (f["width"].as_u64(), f["height"].as_u64()),
            (Some(48), Some(48)),
            "{f}"
        );
        assert_eq!(
            (f["image_width"].as_u64(), f["image_height"].as_u64()),
            (Some(48), Some(48)),
            "{f}"
        );
    }
    for p in &pngs {
        assert!(is_png(p));
        assert_eq!(png_size(p), (48, 48));
    }
    let done = texts.last().unwrap();
    assert_eq!(done["type"], "done", "{texts:?}");
    assert_eq!(done["job"]["state"], "succeeded");
    let stats = &done["job"]["stats"];
    for k in common::STATS_FIELDS {
        assert!(stats.get(k).is_some(), "stats lacks {k}: {stats}");
    }
    assert_eq!(stats["width"], 48);
    assert_eq!(stats["mode"], "progressive");

    // The job object agrees, with timestamps in order.
    let j = s.job(&id).await;
    assert_eq!(j["state"], "succeeded");
    let (c, st, fi) = (
        j["created_at"].as_str().unwrap(),
        j["started_at"].as_str().unwrap(),
        j["finished_at"].as_str().unwrap(),
    );
    assert!(c.ends_with('Z') && c <= st && st <= fi, "{j}");

    // Every layer, as PNG of the image size; the EXR; bad parameters.
    for layer in ["image", "samples", "distance", "classes", "objects"] {
        let r = s.get(&format!("/v1/jobs/{id}/frame?layer={layer}")).await;
        assert_eq!(r.status(), 200, "layer {layer}");
        assert_eq!(r.headers()["content-type"], "image/png");
        let b = r.bytes().await.unwrap();
        assert_eq!(png_size(&b), (48, 48), "layer {layer}");
    }
    let r = s.get(&format!("/v1/jobs/{id}/frame")).await;
    assert_eq!(
        r.bytes().await.unwrap().to_vec(),
        *pngs.last().unwrap(),
        "default layer = last streamed image"
    );
    let r = s.get(&format!("/v1/jobs/{id}/frame?format=exr")).await;
    assert_eq!(r.status(), 200);
    let exr = glimpse::raster::decode_image(&r.bytes().await.unwrap()).unwrap();
    assert_eq!((exr.width(), exr.height()), (48, 48));
    assert!(!exr.has_non_finite());
    assert!(exr.mean()[0] > 0.0, "a lit sphere is not black");
    let r = s.get(&format!("/v1/jobs/{id}/frame?layer=depth")).await;
    assert_eq!(
        error_of(r, 400, "invalid_parameter").await["error"]["path"],
        "layer"
    );
    let r = s.get(&format!("/v1/jobs/{id}/frame?format=gif")).await;
    error_of(r, 400, "invalid_parameter").await;

    // A late joiner on a finished job: state, the stored final frame, done.
    let mut ws = ws_connect(&s, &id, None).await;
    let (texts, pngs) = read_stream(&mut ws, Duration::from_secs(10)).await;
    let kinds: Vec<&str> = texts.iter().map(|t| t["type"].as_str().unwrap()).collect();
    assert_eq!(kinds, ["state", "frame", "done"]);
    assert_eq!(pngs.len(), 1);

    // List: newest first, filters, bad parameters.
    let l: Value = common::get_json(&s.client, &s.url("/v1/jobs")).await;
    let ids: Vec<&str> = l["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, [id.as_str(), blocker.as_str()]);
    let l: Value = common::get_json(&s.client, &s.url("/v1/jobs?state=cancelled")).await;
    assert_eq!(l["jobs"].as_array().unwrap().len(), 1);
    assert_eq!(l["jobs"][0]["id"], blocker.as_str());
    let l: Value = common::get_json(&s.client, &s.url("/v1/jobs?limit=1")).await;
    assert_eq!(l["jobs"].as_array().unwrap().len(), 1);
    for bad in ["state=done", "limit=0", "limit=501", "limit=ten"] {
        let r = s.get(&format!("/v1/jobs?{bad}")).await;
        let b = error_of(r, 400, "invalid_parameter").await;
        assert_eq!(b["error"]["path"], bad.split('=').next().unwrap());
    }

    // Metrics count what happened.
    let m = s.get("/metrics").await.text().await.unwrap();
    assert!(m.contains("glimpse_jobs{state=\"succeeded\"} 1"), "{m}");
    assert!(m.contains("glimpse_jobs{state=\"cancelled\"} 1"), "{m}");
    assert!(m.contains("glimpse_queue_depth 0"), "{m}");
    assert!(m.contains("glimpse_pixels_traced_total "), "{m}");
    assert!(!m.contains("glimpse_pixels_traced_total 0\n"), "{m}");
    assert!(!m.contains("glimpse_render_seconds_total 0.000000"), "{m}");

    // Delete: 204, then gone (404 everywhere), a second delete 404.
    let r = s.delete(&format!("/v1/jobs/{id}")).await;
    assert_eq!(r.status(), 204);
    let r = s.get(&format!("/v1/jobs/{id}")).await;
    error_of(r, 404, "not_found").await;
    let r = s.get(&format!("/v1/jobs/{id}/frame")).await;
    error_of(r, 404, "not_found").await;
    let r = s.delete(&format!("/v1/jobs/{id}")).await;
    error_of(r, 404, "not_found").await;
    s.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancel_frees_the_worker_at_once_and_conflicts_are_409() {
    let s = Server::start(|_| {}).await;
    let long = s.submit(&long_scene()).await;
    s.wait_state(&long, &["running"], Duration::from_secs(10))
        .await;
    // Still running: no delete, and no frame yet (a reference render has one at the end).
    let r = s.delete(&format!("/v1/jobs/{long}")).await;
    error_of(r, 409, "conflict").await;
    let r = s.get(&format!("/v1/jobs/{long}/frame")).await;
    error_of(r, 404, "not_found").await;

    let small = s.submit(&scene(16, 16, "reference", 1)).await;
    let t0 = Instant::now();
    let r = s.cancel(&long).await;
    assert_eq!(r.status(), 202);
    let j = s
        .wait_state(&long, &["cancelled"], Duration::from_secs(5))
        .await;
    assert!(j["finished_at"].is_string());
    // The worker is free at once: the queued job runs to the end right after.
    s.wait_state(&small, &["succeeded"], Duration::from_secs(10))
        .await;
    assert!(
        t0.elapsed() < Duration::from_secs(5),
        "cancel took {:?}",
        t0.elapsed()
    );

    let r = s.cancel(&long).await;
    error_of(r, 409, "conflict").await;
    let r = s.cancel(&small).await;
    error_of(r, 409, "conflict").await;
    // A stream of a cancelled job ends with done and the cancelled state.
    let mut ws = ws_connect(&s, &long, None).await;
    let (texts, _) = read_stream(&mut ws, Duration::from_secs(5)).await;
    assert_eq!(texts.last().unwrap()["type"], "done");
    assert_eq!(texts.last().unwrap()["job"]["state"], "cancelled");
    let r = s.delete(&format!("/v1/jobs/{long}")).await;
    assert_eq!(r.status(), 204);
    s.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_queue_is_429_with_retry_after_and_queued_jobs_cancel_at_once() {
    let s = Server::start(|c| c.queue_capacity = 1).await;
    let a = s.submit(&long_scene()).await;
    s.wait_state(&a, &["running"], Duration::from_secs(10))
        .await;
    let b = s.submit(&long_scene()).await; // waits: the queue is now full
    let r = s.post_scene(&long_scene()).await;
    let retry = r
        .headers()
        .get("retry-after")
        .map(|v| v.to_str().unwrap().parse::<u32>().unwrap());
    assert!(retry.is_some_and(|s| (1..=60).contains(&s)), "{retry:?}");
    error_of(r, 429, "queue_full").await;
    // Cancelling the queued job is immediate and frees its slot.
    let r = s.cancel(&b).await;
    assert_eq!(r.status(), 202);
    assert_eq!(r.json::<Value>().await.unwrap()["state"], "cancelled");
    let c = s.submit(&scene(8, 8, "reference", 1)).await;
    let r = s.cancel(&a).await;
    assert_eq!(r.status(), 202);
    s.wait_state(&c, &["succeeded"], Duration::from_secs(10))
        .await;
    assert_eq!(s.job(&b).await["state"], "cancelled");
    s.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn routes_ids_and_methods_answer_json_errors() {
    let s = Server::start(|_| {}).await;
    let c = &s.client;
    for (path, status, code) in [
        ("/v1/jobs/not-a-uuid", 404, "not_found"),
        (
            "/v1/jobs/0193a1b2-0000-7000-8000-000000000000",
            404,
            "not_found",
        ),
        (
            "/v1/jobs/0193a1b2-0000-7000-8000-000000000000/frame",
            404,
            "not_found",
        ),
        ("/v1/jobs/..%2F..%2Fetc%2Fpasswd/frame", 404, "not_found"),
        ("/v1/nothing", 404, "not_found"),
        ("/nothing", 404, "not_found"),
    ] {
        let r = c.get(s.url(path)).send().await.unwrap();
        error_of(r, status, code).await;
    }
    let r = c
        .post(s.url("/v1/jobs/0193a1b2-0000-7000-8000-000000000000/cancel"))
        .send()
        .await
        .unwrap();
    error_of(r, 404, "not_found").await;
    let r = c.delete(s.url("/v1/jobs/zzz")).send().await.unwrap();
    error_of(r, 404, "not_found").await;
    let r = c.put(s.url("/v1/jobs")).send().await.unwrap();
    error_of(r, 405, "method_not_allowed").await;
    // Not a WebSocket request on the stream route.
    let id = s.submit(&scene(8, 8, "reference", 1)).await;
    let r = c
        .get(s.url(&format!("/v1/jobs/{id}/stream")))
        .send()
        .await
        .unwrap();
    assert!(r.status().is_client_error());
    let b: Value = r.json().await.unwrap();
    assert!(b["error"]["code"].is_string(), "{b}");
    // Open routes.
    let r = c.get(s.url("/")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert!(r.headers()["content-type"]
        .to_str()
        .unwrap()
        .starts_with("text/html"));
    let r = c.get(s.url("/v1/examples")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    let ex: Value = r.json().await.unwrap();
    assert!(!ex["examples"].as_array().unwrap().is_empty(), "{ex}");
    for e in ex["examples"].as_array().unwrap() {
        assert!(e["name"].is_string() && e["scene"].is_object(), "{e}");
    }
    s.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_token_guards_v1_but_not_health_viewer_or_metrics() {
    let s = Server::start(|c| c.token = Some("s3cret".into())).await;
    let c = &s.client;
    let r = c.get(s.url("/v1/jobs")).send().await.unwrap();
    assert_eq!(r.headers()["www-authenticate"], "Bearer");
    error_of(r, 401, "unauthorized").await;
    let r = c
        .get(s.url("/v1/jobs"))
        .bearer_auth("wrong")
        .send()
        .await
        .unwrap();
    error_of(r, 401, "unauthorized").await;
    let r = c
        .post(s.url("/v1/jobs"))
        .json(&scene(8, 8, "reference", 1))
        .send()
        .await
        .unwrap();
    error_of(r, 401, "unauthorized").await;
    // `?token=` is for WebSockets only.
    let r = c.get(s.url("/v1/jobs?token=s3cret")).send().await.unwrap();
    error_of(r, 401, "unauthorized").await;
    for open in ["/", "/healthz", "/metrics"] {
        assert_eq!(
            c.get(s.url(open)).send().await.unwrap().status(),
            200,
            "{open}"
        );
    }
    let r = c
        .post(s.url("/v1/jobs"))
        .bearer_auth("s3cret")
        .json(&scene(8, 8, "reference", 1))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let id = r.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned();
    // WebSocket: refused without the token, served with `?token=`.
    let refused =
        tokio_tungstenite::connect_async(format!("ws://{}/v1/jobs/{id}/stream", s.addr)).await;
    assert!(refused.is_err());
    let mut ws = ws_connect(&s, &id, Some("s3cret")).await;
    let (texts, _) = read_stream(&mut ws, Duration::from_secs(10)).await;
    assert_eq!(texts.first().unwrap()["type"], "state");
    assert_eq!(texts.last().unwrap()["type"], "done");
    s.stop().await.unwrap();
}

/// tests/scenes-bad/: each NAME.json must get the code on line 1 of NAME.expect and the
/// JSON path on line 2 (see its README.md); the server stays healthy throughout.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_scenes_get_their_code_and_path() {
    let s = Server::start(|_| {}).await;
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scenes-bad");
    let mut cases: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .collect();
    cases.sort();
    assert!(!cases.is_empty(), "no cases in {}", dir.display());
    let mut failures = Vec::new();
    for case in &cases {
        let body = std::fs::read(case).unwrap();
        let expect = std::fs::read_to_string(case.with_extension("expect")).unwrap();
        let mut lines = expect.lines();
        let code = lines.next().unwrap_or("").trim().to_owned();
        let path = lines.next().unwrap_or("").trim().to_owned();
        let r = s
            .client
            .post(s.url("/v1/jobs"))
            .header("content-type", "application/json")
            .body(body)
            .send()
            .await
            .unwrap();
        let status = r.status().as_u16();
        let b: Value = r.json().await.unwrap_or(Value::Null);
        let want_status = match code.as_str() {
            "invalid_json" => 400,
            "invalid_scene" | "over_limit" => 422,
            other => panic!("{}: unknown expected code {other}", case.display()),
        };
        if status != want_status
            || b["error"]["code"] != code.as_str()
            || b["error"]["path"] != path.as_str()
        {
            failures.push(format!(
                "{}: want {want_status} {code} at {path:?}, got {status} {b}",
                case.display()
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert_eq!(s.get("/healthz").await.status(), 200);
    let l: Value = common::get_json(&s.client, &s.url("/v1/jobs")).await;
    assert_eq!(
        l["jobs"].as_array().unwrap().len(),
        0,
        "no bad document became a job"
    );
    s.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_http_bodies_get_4xx_json_and_the_server_survives() {
    let s = Server::start(|c| c.max_body_bytes = 1 << 20).await;
    let c = &s.client;
    let good = scene(8, 8, "reference", 1).to_string();
    let nested = format!("{}{}", "[".repeat(100_000), "]".repeat(100_000));
    let nested_obj = format!("{}1{}", "{\"a\":".repeat(10_000), "}".repeat(10_000));
    let cases: Vec<(&str, Vec<u8>, u16, &str)> = vec![
        ("not json", b"hello, server".to_vec(), 400, "invalid_json"),
        ("empty", Vec::new(), 400, "invalid_json"),
        ("whitespace", b"  \n ".to_vec(), 400, "invalid_json"),
        (
            "truncated",
            good.as_bytes()[..good.len() / 2].to_vec(),
            400,
            "invalid_json",
        ),
        (
            "not utf-8",
            vec![0xff, 0xfe, b'{', b'}'],
            400,
            "invalid_json",
        ),
        (
            "deeply nested array",
            nested.into_bytes(),
            400,
            "invalid_json",
        ),
        (
            "deeply nested object",
            nested_obj.into_bytes(),
            400,
            "invalid_json",
        ),
        (
            "NaN literal",
            good.replace("\"width\":8", "\"width\":NaN").into_bytes(),
            400,
            "invalid_json",
        ),
        (
            "Infinity literal",
            good.replace("\"fov_y\":40", "\"fov_y\":Infinity")
                .into_bytes(),
            400,
            "invalid_json",
        ),
        ("array body", b"[1, 2, 3]".to_vec(), 422, "invalid_scene"),
        ("oversized", vec![b' '; (1 << 20) + 1], 413, "too_large"),
    ];
    for (what, body, status, code) in cases {
        let r = c
            .post(s.url("/v1/jobs"))
            .header("content-type", "application/json")
            .body(body)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), status, "{what}");
        let b: Value = r
            .json()
            .await
            .unwrap_or_else(|e| panic!("{what}: body is not JSON: {e}"));
        assert_eq!(b["error"]["code"], code, "{what}: {b}");
    }
    // Numbers out of range: refused as a scene problem or as JSON, always at the field.
    for (what, doc, field) in [
        (
            "huge width",
            good.replace("\"width\":8", "\"width\":1e999"),
            "image.width",
        ),
        (
            "negative width",
            good.replace("\"width\":8", "\"width\":-8"),
            "image.width",
        ),
        (
            "width above u32",
            good.replace("\"width\":8", "\"width\":99999999999"),
            "image.width",
        ),
    ] {
        let r = c
            .post(s.url("/v1/jobs"))
            .header("content-type", "application/json")
            .body(doc)
            .send()
            .await
            .unwrap();
        let st = r.status().as_u16();
        let b: Value = r.json().await.unwrap();
        assert!(matches!(st, 400 | 413 | 422), "{what}: {st} {b}");
        if st != 400 {
            assert_eq!(b["error"]["path"], field, "{what}: {b}");
        }
    }
    // A chunked body (no Content-Length) over the limit is refused too: raw HTTP/1.1.
    {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut sock = tokio::net::TcpStream::connect(s.addr).await.unwrap();
        let head = "POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n";
        sock.write_all(head.as_bytes()).await.unwrap();
        let chunk = vec![b' '; 64 * 1024];
        for _ in 0..20 {
            // The server may answer and close early: stop writing then.
            if sock
                .write_all(format!("{:x}\r\n", chunk.len()).as_bytes())
                .await
                .is_err()
                || sock.write_all(&chunk).await.is_err()
                || sock.write_all(b"\r\n").await.is_err()
            {
                break;
            }
        }
        let _ = sock.write_all(b"0\r\n\r\n").await;
        let mut resp = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(5), sock.read_to_end(&mut resp)).await;
        let resp = String::from_utf8_lossy(&resp);
        assert!(resp.starts_with("HTTP/1.1 413"), "{resp}");
        assert!(resp.contains("\"too_large\""), "{resp}");
    }
    // Limits of the scene itself are parameters, not a body too large: 422 `over_limit`,
    // naming the limit and the server flag that raises it.
    let r = s.post_scene(&scene(20000, 20000, "reference", 1)).await;
    let b = error_of(r, 422, "over_limit").await;
    assert!(
        b["error"]["path"].as_str().unwrap().starts_with("image"),
        "{b}"
    );
    let m = b["error"]["message"].as_str().unwrap();
    assert!(
        m.contains("limit of 4096") && m.contains("glimpse serve --max-width"),
        "{m}"
    );
    // No `obj` object over the network: the server never reads its own files.
    let mut sc = scene(8, 8, "reference", 1);
    sc["objects"] = json!([{ "type": "obj", "path": "/etc/passwd", "material": "white" }]);
    let r = s.post_scene(&sc).await;
    let b = error_of(r, 422, "invalid_scene").await;
    assert!(
        b["error"]["path"]
            .as_str()
            .unwrap()
            .starts_with("objects[0]"),
        "{b}"
    );

    assert_eq!(c.get(s.url("/healthz")).send().await.unwrap().status(), 200);
    let id = s.submit(&scene(8, 8, "reference", 1)).await;
    s.wait_state(&id, &["succeeded"], Duration::from_secs(10))
        .await;
    s.stop().await.unwrap();
}

/// The warnings of the 201 (here a bounce limit above the server's cap) stay with the job:
/// its `GET`, the list, the stream's `state` and `done`, and after a restart (on a shared
/// database, what any node reads).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_jobs_warnings_are_kept_and_shown_wherever_the_job_is() {
    let dir = tempfile::tempdir().unwrap();
    let capped = |c: &mut glimpse::service::Config| c.limits.max_bounces = 1;
    let s = Server::start_in(dir.path(), capped).await;
    let r = s.post_scene(&scene(16, 16, "reference", 1)).await;
    assert_eq!(r.status(), 201);
    let created: Value = r.json().await.unwrap();
    let warnings = created["warnings"].clone();
    let listed = warnings.as_array().expect("the 201's warnings");
    assert_eq!(listed.len(), 1, "{created}");
    assert!(
        listed[0]
            .as_str()
            .unwrap()
            .starts_with("render.max_bounces: 2 is above"),
        "{created}"
    );
    let id = created["id"].as_str().unwrap().to_owned();
    let mut ws = ws_connect(&s, &id, None).await;
    let (texts, _) = read_stream(&mut ws, Duration::from_secs(30)).await;
    let state = texts.first().unwrap();
    assert_eq!(state["type"], "state", "{state}");
    assert_eq!(state["job"]["warnings"], warnings, "{state}");
    let done = texts.last().unwrap();
    assert_eq!(done["type"], "done", "{done}");
    assert_eq!(done["job"]["warnings"], warnings, "{done}");
    assert_eq!(s.job(&id).await["warnings"], warnings);
    let list: Value = s.get("/v1/jobs").await.json().await.unwrap();
    assert_eq!(list["jobs"][0]["id"], id.as_str());
    assert_eq!(list["jobs"][0]["warnings"], warnings);
    // A job without warnings has none in any of these.
    let quiet = Server::start(|_| {}).await;
    let other = quiet.submit(&scene(8, 8, "reference", 1)).await;
    assert!(quiet.job(&other).await.get("warnings").is_none());
    quiet.stop().await.unwrap();
    // Read back from the store after a restart, without the cap.
    s.stop().await.unwrap();
    let s = Server::start_in(dir.path(), |_| {}).await;
    assert_eq!(s.job(&id).await["warnings"], warnings);
    s.stop().await.unwrap();
}

/// Graceful shutdown puts a running job back to `queued`; the next start runs it to the end.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_requeues_running_jobs_and_a_restart_finishes_them() {
    let dir = tempfile::tempdir().unwrap();
    let s = Server::start_in(dir.path(), |_| {}).await;
    let long = s.submit(&long_scene()).await;
    let small = s.submit(&scene(8, 8, "reference", 1)).await;
    s.wait_state(&long, &["running"], Duration::from_secs(10))
        .await;
    let mut ws = ws_connect(&s, &long, None).await;
    let t0 = Instant::now();
    s.stop().await.unwrap();
    assert!(
        t0.elapsed() < Duration::from_secs(5),
        "shutdown took {:?}",
        t0.elapsed()
    );
    // The stream was closed by the server, not left hanging.
    let _ = read_stream(&mut ws, Duration::from_secs(5)).await;

    // Restart with a cheaper limit check: the long job would take long, so cancel it and
    // watch the small one (queued behind it) complete; the long one was requeued.
    let s = Server::start_in(dir.path(), |_| {}).await;
    let j = s.job(&long).await;
    assert!(j["state"] == "queued" || j["state"] == "running", "{j}");
    assert!(j["finished_at"].is_null(), "{j}");
    let r = s.cancel(&long).await;
    assert_eq!(r.status(), 202);
    s.wait_state(&small, &["succeeded"], Duration::from_secs(10))
        .await;
    s.stop().await.unwrap();
}

/// Many watchers on one job all get the end; the WebSocket gauge goes back to zero.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn many_watchers_share_one_job() {
    let s = Server::start(|_| {}).await;
    let id = s.submit(&scene(32, 32, "progressive", 4)).await;
    let mut socks = Vec::new();
    for _ in 0..8 {
        socks.push(ws_connect(&s, &id, None).await);
    }
    for ws in &mut socks {
        let (texts, pngs) = read_stream(ws, Duration::from_secs(30)).await;
        assert_eq!(texts.first().unwrap()["type"], "state");
        assert_eq!(texts.last().unwrap()["type"], "done", "{texts:?}");
        assert!(!pngs.is_empty(), "everyone gets at least the final frame");
        let _ = ws.close(None).await;
    }
    drop(socks);
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let m = s.get("/metrics").await.text().await.unwrap();
        if m.contains("glimpse_websocket_watchers 0") {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "watchers never went back to 0: {m}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // A client that connects and says nothing does not hold the server: close it.
    let mut ws = ws_connect(&s, &id, None).await;
    ws.send(Message::Close(None)).await.unwrap();
    // What a client sends is read and dropped; a message over the limit ends its stream
    // (the server must not buffer it), while one under it changes nothing. The job is long
    // (cancelled at the end), so the oversized stream cannot have ended by running out.
    let long = s.submit(&long_scene()).await;
    s.wait_state(&long, &["running"], Duration::from_secs(10))
        .await;
    let mut small = ws_connect(&s, &long, None).await;
    let mut big = ws_connect(&s, &long, None).await;
    small
        .send(Message::Binary(vec![7u8; 1000].into()))
        .await
        .unwrap();
    let _ = big
        .send(Message::Binary(
            vec![7u8; glimpse::service::ws::MAX_CLIENT_MESSAGE + 1].into(),
        ))
        .await;
    let ended = tokio::time::timeout(Duration::from_secs(10), async {
        loop {
            match big.next().await {
                Some(Ok(Message::Close(_)) | Err(_)) | None => break,
                Some(Ok(_)) => {}
            }
        }
    })
    .await;
    assert!(ended.is_ok(), "the oversized stream was not ended");
    assert_eq!(s.job(&long).await["state"], "running");
    let r = s.cancel(&long).await;
    assert_eq!(r.status(), 202);
    let (texts, _) = read_stream(&mut small, Duration::from_secs(30)).await;
    assert_eq!(texts.last().unwrap()["type"], "done", "{texts:?}");
    s.stop().await.unwrap();
}

/// The files beside a finished job are written after its `done` (only the image and the
/// record must be on disk before it): a client asking for any layer the moment `done`
/// arrives still gets it complete, and a DELETE at once removes everything.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_layer_asked_right_after_done_is_complete_and_delete_at_once_is_clean() {
    let s = Server::start(|_| {}).await;
    let (w, h) = (48, 32);
    let id = s.submit(&scene(w, h, "progressive", 4)).await;
    let mut ws = ws_connect(&s, &id, None).await;
    let mut last_png = Vec::new();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    loop {
        let m = tokio::time::timeout_at(deadline, ws.next())
            .await
            .expect("no done in time")
            .expect("stream ended before done")
            .unwrap();
        match m {
            Message::Binary(b) => last_png = b.to_vec(),
            Message::Text(t) => {
                let v: Value = serde_json::from_str(&t).unwrap();
                assert_ne!(v["type"], "error", "{v}");
                if v["type"] == "done" {
                    assert_eq!(v["job"]["state"], "succeeded", "{v}");
                    break;
                }
            }
            _ => {}
        }
    }
    // All at once, right after `done`.
    let queries = [
        "layer=image",
        "layer=samples",
        "layer=distance",
        "layer=classes",
        "format=exr",
    ];
    let gets = queries.map(|q| {
        s.client
            .get(s.url(&format!("/v1/jobs/{id}/frame?{q}")))
            .send()
    });
    let answers = futures_util::future::join_all(gets).await;
    for (q, r) in queries.iter().zip(answers) {
        let r = r.unwrap();
        assert_eq!(r.status(), 200, "{q}");
        let b = r.bytes().await.unwrap();
        let img = glimpse::raster::decode_image(&b).unwrap();
        assert_eq!((img.width(), img.height()), (w, h), "{q}");
        if *q == "layer=image" {
            assert_eq!(
                b.to_vec(),
                last_png,
                "the streamed final frame is the stored one"
            );
        }
    }
    let r = s.delete(&format!("/v1/jobs/{id}")).await;
    assert_eq!(r.status(), 204);
    let r = s.get(&format!("/v1/jobs/{id}/frame?layer=samples")).await;
    error_of(r, 404, "not_found").await;
    s.stop().await.unwrap();
}

/// Slow clients cannot hold connections for good ("slowloris"): half a header is dropped
/// after the header timeout, a trickled body gets `408 request_timeout` at the request
/// deadline, while a stream (whose request ends with the upgrade) outlives both and other
/// clients are served throughout.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_headers_and_bodies_are_cut_but_streams_are_not() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let s = Server::start(|c| {
        c.header_timeout = Duration::from_millis(300);
        c.request_deadline = Duration::from_millis(600);
    })
    .await;
    let long = s.submit(&long_scene()).await;
    let mut ws = ws_connect(&s, &long, None).await;

    // Half a header, nothing at all, or nothing after a first request (an idle keep-alive
    // connection): closed after the header timeout, without an answer to the unfinished.
    let mut half = tokio::net::TcpStream::connect(s.addr).await.unwrap();
    half.write_all(b"GET /healthz HTTP/1.1\r\nHo")
        .await
        .unwrap();
    let silent = tokio::net::TcpStream::connect(s.addr).await.unwrap();
    let mut idle = tokio::net::TcpStream::connect(s.addr).await.unwrap();
    idle.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        .await
        .unwrap();
    let t = Instant::now();
    for (what, mut conn, answered) in [
        ("half", half, false),
        ("silent", silent, false),
        ("idle", idle, true),
    ] {
        let mut buf = Vec::new();
        let n = tokio::time::timeout(Duration::from_secs(5), conn.read_to_end(&mut buf))
            .await
            .unwrap_or_else(|_| panic!("a {what} connection was held"));
        let text = String::from_utf8_lossy(&buf);
        assert_eq!(
            n.is_ok() && text.starts_with("HTTP/1.1 200"),
            answered,
            "{what}: {text}"
        );
    }
    assert!(
        t.elapsed() >= Duration::from_millis(250),
        "{:?}",
        t.elapsed()
    );

    // A body promised but not sent: 408 in our JSON error shape, then the server closes.
    let mut slow = tokio::net::TcpStream::connect(s.addr).await.unwrap();
    slow.write_all(
        b"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n\
          Content-Length: 1000\r\n\r\n{\"ver",
    )
    .await
    .unwrap();
    let mut buf = Vec::new();
    tokio::time::timeout(Duration::from_secs(5), slow.read_to_end(&mut buf))
        .await
        .expect("a trickled body held the connection")
        .unwrap();
    let text = String::from_utf8_lossy(&buf);
    assert!(text.starts_with("HTTP/1.1 408"), "{text}");
    assert!(text.contains("\"code\":\"request_timeout\""), "{text}");

    // Others are served meanwhile, and the stream opened before is still open, past both
    // timeouts: it gets the cancelled job's `done`.
    assert_eq!(s.job(&long).await["state"], "running");
    let r = s.cancel(&long).await;
    assert_eq!(r.status(), 202);
    let (texts, _) = read_stream(&mut ws, Duration::from_secs(30)).await;
    assert_eq!(texts.first().unwrap()["type"], "state");
    assert_eq!(texts.last().unwrap()["type"], "done", "{texts:?}");
    s.stop().await.unwrap();
}
