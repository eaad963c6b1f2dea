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
