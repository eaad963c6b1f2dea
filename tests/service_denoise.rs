//! The denoiser over HTTP, against the real server and the real library: an adaptive job
//! streams denoised frames and says so; a server without the library refuses a job that
//! asks to denoise (503 `denoiser_unavailable`, naming what is missing and how to add
//! it) and still takes every job that does not; a cluster's worker without it fails such
//! a job with the same code instead of returning it noisy.

mod common;

use common::LIT_SCENE;
use futures_util::StreamExt;
use std::time::Duration;
use tokio_tungstenite::tungstenite::Message;

fn adaptive(denoise: Option<bool>) -> String {
    let field = denoise.map_or(String::new(), |d| format!(r#", "denoise": {d}"#));
    let s = LIT_SCENE.replace(
        r#""mode": "progressive", "samples_per_pixel": 4,"#,
        &format!(r#""mode": "adaptive"{field}, "samples_per_pixel": 64,"#),
    );
    assert_ne!(s, LIT_SCENE, "the mode was changed");
    s
}

fn json(text: &str) -> serde_json::Value {
    serde_json::from_str(text).expect("a JSON document")
}

async fn post(c: &reqwest::Client, base: &str, body: String) -> reqwest::Response {
    c.post(format!("{base}/v1/jobs"))
        .header("content-type", "application/json")
        .body(body)
        .send()
        .await
        .unwrap()
}

#[tokio::test]
async fn an_adaptive_job_streams_denoised_frames_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let _server = common::spawn(dir.path(), port, None, &[], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");
    let id = common::submit(&c, &base, &json(&adaptive(None))).await;
    let (mut ws, _) =
        tokio_tungstenite::connect_async(format!("ws://127.0.0.1:{port}/v1/jobs/{id}/stream"))
            .await
            .expect("the stream opens");
    let mut frames = 0;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(120);
    while let Ok(Some(Ok(m))) = tokio::time::timeout_at(deadline, ws.next()).await {
        let Message::Text(t) = m else { continue };
        let v: serde_json::Value = serde_json::from_str(&t).unwrap();
        match v["type"].as_str() {
            Some("frame") if v["preview"] != true => {
                assert_eq!(v["progress"]["denoised"], true, "{v}");
                frames += 1;
            }
            Some("done") => {
                let job = &v["job"];
                assert_eq!(job["state"], "succeeded", "{v}");
                assert_eq!(job["stats"]["mode"], "adaptive", "{v}");
                assert_eq!(job["stats"]["denoised"], true, "{v}");
                assert!(job["stats"]["samples_traced"].as_u64().unwrap() > 0, "{v}");
                break;
            }
            Some("error") => panic!("{v}"),
            _ => {}
        }
    }
    assert!(frames >= 1, "no frame streamed");
}

#[tokio::test]
async fn without_the_library_a_job_that_denoises_is_refused_and_others_run() {
    let dir = tempfile::tempdir().unwrap();
    let empty = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let oidn = empty.path().to_str().unwrap();
    let _server = common::spawn(
        dir.path(),
        port,
        None,
        &[],
        &[("GLIMPSE_OIDN_DIR", oidn)],
        &c,
    )
    .await;
    let base = format!("http://127.0.0.1:{port}");
    let r = post(&c, &base, adaptive(None)).await;
    assert_eq!(r.status(), 503);
    let e: serde_json::Value = r.json().await.unwrap();
    assert_eq!(e["error"]["code"], "denoiser_unavailable", "{e}");
    assert_eq!(e["error"]["path"], "render.denoise", "{e}");
    let msg = e["error"]["message"].as_str().unwrap();
    for needle in [
        "bash scripts/oidn.sh",
        "GLIMPSE_OIDN_DIR",
        oidn,
        "render.denoise to false",
    ] {
        assert!(msg.contains(needle), "no {needle:?} in {msg}");
    }
    // Adaptive without the denoiser, and a plain progressive job, run.
    for body in [adaptive(Some(false)), LIT_SCENE.to_owned()] {
        let id = common::submit(&c, &base, &json(&body)).await;
        common::wait_state(&c, &base, &id, "succeeded", Duration::from_secs(60)).await;
        let job = common::job(&c, &base, &id).await;
        assert_eq!(job["stats"]["denoised"], false, "{job}");
    }
}

#[tokio::test]
async fn a_worker_without_the_library_fails_a_denoising_job_saying_why() {
    let url = common::fresh_pg_database().await;
    let dir = tempfile::tempdir().unwrap();
    let empty = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let addr = format!("127.0.0.1:{port}");
    let data = dir.path().to_str().unwrap();
    let api = [
        "serve",
        "--addr",
        &addr,
        "--workers",
        "0",
        "--database",
        &url,
        "--data",
        data,
    ];
    let _api = common::glimpse(&api, &dir.path().join("api.log"), "warn");
    let c = reqwest::Client::new();
    let base = format!("http://{addr}");
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    while c.get(format!("{base}/healthz")).send().await.is_err() {
        assert!(
            std::time::Instant::now() < deadline,
            "the API node did not come up"
        );
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    // The API node has the library: the job is accepted.
    let r = post(&c, &base, adaptive(None)).await;
    assert_eq!(r.status(), 201);
    let id = r.json::<serde_json::Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned();
    let worker = std::process::Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .args([
            "worker",
            "--database",
            &url,
            "--data",
            data,
            "--threads",
            "1",
        ])
        .env("GLIMPSE_OIDN_DIR", empty.path())
        .env("RUST_LOG", "warn")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let _worker = common::Proc(worker);
    common::wait_state(&c, &base, &id, "failed", Duration::from_secs(60)).await;
    let job = common::job(&c, &base, &id).await;
    assert_eq!(job["error"]["code"], "denoiser_unavailable", "{job}");
    let msg = job["error"]["message"].as_str().unwrap();
    assert!(msg.contains("bash scripts/oidn.sh"), "{msg}");
}

/// Starts a job of `scene`; when it runs, waits `after` and cancels it: the job must end
/// `cancelled` (never `succeeded`, whatever phase the cancel met) and free its worker at
/// once. Returns the time from the cancel's answer to the job's end, or `None` when the
/// job had already finished (409: the cancel came too late to test anything).
async fn cancel_after(
    c: &reqwest::Client,
    base: &str,
    scene: &serde_json::Value,
    after: Duration,
) -> Option<Duration> {
    let id = common::submit(c, base, scene).await;
    common::wait_states(c, base, &id, &["running"], Duration::from_secs(60)).await;
    tokio::time::sleep(after).await;
    let r = c
        .post(format!("{base}/v1/jobs/{id}/cancel"))
        .send()
        .await
        .unwrap();
    let asked = tokio::time::Instant::now();
    if r.status() == 409 {
        return None;
    }
    assert_eq!(r.status(), 202, "cancel refused");
    let j = common::wait_states(
        c,
        base,
        &id,
        &["cancelled", "succeeded", "failed"],
        Duration::from_secs(60),
    )
    .await;
    let took = asked.elapsed();
    assert_eq!(
        j["state"], "cancelled",
        "a cancel after {after:?} was lost: {j}"
    );
    Some(took)
}

/// Cancels at every phase of a denoising render (tracing, the guides, the denoise itself)
/// in the reference mode with `denoise` and in adaptive mode: each ends `cancelled`, its
/// worker free within a fraction of a second (the denoiser is stopped from its progress
/// monitor, and a cancel that comes as the render ends wins over it).
#[tokio::test]
async fn a_cancel_ends_a_denoising_job_at_any_phase() {
    let dir = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let _server = common::spawn(dir.path(), port, None, &[], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");
    for mode in ["reference", "adaptive"] {
        let mut scene = common::sphere_scene("cancel", 768, 768, mode, 2, 1);
        scene["render"]["denoise"] = serde_json::json!(true);
        // Its whole length first, then cancels spread over it.
        let id = common::submit(&c, &base, &scene).await;
        let done =
            common::wait_states(&c, &base, &id, &["succeeded"], Duration::from_secs(120)).await;
        let stats = &done["stats"];
        let total = stats["total_ms"].as_f64().unwrap();
        let denoise = stats["denoise_ms"].as_f64().unwrap();
        assert!(denoise > 0.0, "{mode}: {stats}");
        // Into the last denoise (its middle and near its end), then earlier phases.
        let mut took = Vec::new();
        for at in [
            total - denoise / 2.0,
            total - denoise / 8.0,
            total / 3.0,
            total / 10.0,
        ] {
            let after = Duration::from_secs_f64(at.max(0.0) / 1e3);
            took.extend(cancel_after(&c, &base, &scene, after).await);
        }
        let worst = took.iter().max().copied().unwrap_or_default();
        eprintln!(
            "{mode}: {total:.0} ms in all, {denoise:.0} ms denoising; {} cancels landed, slowest {worst:?}",
            took.len()
        );
        assert!(took.len() >= 3, "{mode}: too few cancels landed to judge");
        // The job's end as a poller sees it: the worker's own delay is measured apart
        // (docs/measurements.md); this bounds it on a loaded machine.
        assert!(
            worst < Duration::from_secs(2),
            "{mode}: a cancel took {worst:?}"
        );
    }
}

/// A job whose size, mode and denoiser would need more memory than the server gives one
/// job is refused before it is queued, naming the flag that raises the budget; the same
/// image without the denoiser, or smaller, fits.
#[tokio::test]
async fn a_job_beyond_the_memory_budget_is_refused_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let _server = common::spawn(dir.path(), port, None, &["--max-job-memory", "1"], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");
    let mut big = common::sphere_scene("big", 2048, 2048, "adaptive", 1, 1);
    big["render"]["denoise"] = serde_json::json!(true);
    let r = post(&c, &base, big.to_string()).await;
    assert_eq!(r.status(), 422);
    let v: serde_json::Value = r.json().await.unwrap();
    assert_eq!(v["error"]["code"], "over_limit", "{v}");
    assert_eq!(v["error"]["path"], "image", "{v}");
    let msg = v["error"]["message"].as_str().unwrap();
    assert!(
        msg.contains("2048×2048") && msg.contains("adaptive") && msg.contains("--max-job-memory"),
        "{msg}"
    );
    // Fits: the same size raw in the reference mode, and a small denoised one.
    let mut raw = common::sphere_scene("raw", 2048, 2048, "reference", 1, 1);
    raw["render"]["denoise"] = serde_json::json!(false);
    let mut small = common::sphere_scene("small", 256, 256, "adaptive", 2, 1);
    small["render"]["denoise"] = serde_json::json!(true);
    for scene in [raw, small] {
        let r = post(&c, &base, scene.to_string()).await;
        assert_eq!(r.status(), 201, "{}", r.text().await.unwrap());
    }
}
