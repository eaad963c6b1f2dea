//! Durability (service-api.md): the real binary is killed with SIGKILL while jobs run,
//! started again on the same data folder, and every accepted job still succeeds; a job
//! finished before the crash keeps its state, statistics and final image.

mod common;

use common::{free_port, job, submit, wait_state, Proc};
use serde_json::Value;
use std::time::{Duration, Instant};

fn scene(w: u32, spp: u32, mode: &str, seed: u64) -> Value {
    common::sphere_scene(&format!("job-{seed}"), w, w, mode, spp, seed)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_then_restart_loses_no_job() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let base = format!("http://127.0.0.1:{port}");
    let c = reqwest::Client::new();
    let server = spawn(dir.path(), port, &c).await;

    // One job finished before the crash.
    let done_id = submit(&c, &base, &scene(16, 1, "reference", 0)).await;
    wait_state(&c, &base, &done_id, "succeeded", Duration::from_secs(20)).await;
    let png_before = c
        .get(format!("{base}/v1/jobs/{done_id}/frame"))
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap();

    // Several accepted jobs, the first long enough to be caught running.
    let mut ids = Vec::new();
    for (k, (w, spp, mode)) in [
        (128, 256, "reference"),
        (32, 4, "progressive"),
        (24, 2, "reference"),
        (32, 4, "progressive"),
    ]
    .into_iter()
    .enumerate()
    {
        ids.push(submit(&c, &base, &scene(w, spp, mode, k as u64 + 1)).await);
    }
    wait_state(&c, &base, &ids[0], "running", Duration::from_secs(20)).await;
    server.kill_hard(); // SIGKILL: no shutdown code runs

    let server = spawn(dir.path(), port, &c).await;
    // The finished job kept everything.
    let j = job(&c, &base, &done_id).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    assert_eq!(j["stats"]["width"], 16, "{j}");
    let png_after = c
        .get(format!("{base}/v1/jobs/{done_id}/frame"))
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap();
    assert_eq!(png_before, png_after);
    // Every job accepted before the crash runs to the end, the interrupted one included.
    let deadline = Instant::now() + Duration::from_secs(120);
    for id in &ids {
        loop {
            let j = job(&c, &base, id).await;
            match j["state"].as_str().unwrap() {
                "succeeded" => {
                    assert!(j["stats"]["pixels_traced"].as_u64().unwrap() > 0, "{j}");
                    break;
                }
                "queued" | "running" => {}
                other => panic!("job {id} ended {other}: {j}"),
            }
            assert!(
                Instant::now() < deadline,
                "job {id} did not finish after the restart"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let r = c
            .get(format!("{base}/v1/jobs/{id}/frame"))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
    }
    let l: Value = common::get_json(&c, &format!("{base}/v1/jobs")).await;
    assert_eq!(l["jobs"].as_array().unwrap().len(), 5);
    drop(server);
}

/// Graceful shutdown: SIGTERM during a render stops the server promptly and
/// cleanly; the interrupted job is queued again and completes after a restart.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_during_a_render_requeues_and_the_restart_completes_it() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let base = format!("http://127.0.0.1:{port}");
    let c = reqwest::Client::new();
    let server = spawn(dir.path(), port, &c).await;

    let id = submit(&c, &base, &scene(128, 1024, "reference", 7)).await;
    wait_state(&c, &base, &id, "running", Duration::from_secs(20)).await;
    let status = server.terminate().await;
    assert!(
        status.success(),
        "graceful shutdown must exit 0, got {status}"
    );

    let _server = spawn(dir.path(), port, &c).await;
    // Interrupted, not finished: the shutdown put it back in the queue.
    let j = job(&c, &base, &id).await;
    assert!(
        j["state"] == "queued" || j["state"] == "running",
        "the job should have been interrupted by SIGTERM: {j}"
    );
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let j = job(&c, &base, &id).await;
        match j["state"].as_str().unwrap() {
            "succeeded" => break,
            "queued" | "running" => {}
            other => panic!("job ended {other} after the restart: {j}"),
        }
        assert!(
            Instant::now() < deadline,
            "job did not finish after the restart"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

async fn spawn(data: &std::path::Path, port: u16, c: &reqwest::Client) -> Proc {
    common::spawn(data, port, None, &["--workers", "1"], &[], c).await
}
