//! Storage faults injected at every write of the store and of the job files
//! (`service::store::fault`, enabled by `GLIMPSE_FAULTS`), against the real server binary.
//! For each write in turn, while it fails: a submission, a cancel of a queued and of a
//! running job, and a `DELETE` answer either normally or `503` with `Retry-After` in the
//! error shape; `/healthz` reports the fault; no job is `succeeded` without its image; a
//! job whose end cannot be stored stays `running` (live, its worker retrying) and one
//! that cannot start stays `queued`. Once the write works again, without a restart,
//! every job reaches the state it was asked for and new work runs. Start-up recovery and
//! the graceful shutdown's requeue are faulted across a restart.
//! `service_storage` does the same on a real full filesystem.

mod common;

use common::{free_port, submit, wait_states, Proc};
use glimpse::service::store::fault::Write;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

struct Srv {
    base: String,
    port: u16,
    c: reqwest::Client,
    rules: PathBuf,
}

impl Srv {
    async fn spawn(&self, data: &Path) -> Proc {
        let rules = self.rules.to_str().unwrap();
        common::spawn(
            data,
            self.port,
            None,
            &["--workers", "1"],
            &[("GLIMPSE_FAULTS", rules)],
            &self.c,
        )
        .await
    }

    fn url(&self, p: &str) -> String {
        format!("{}{p}", self.base)
    }

    /// Makes the writes `rules` names fail from now on.
    fn fail(&self, rules: &str) {
        std::fs::write(&self.rules, rules).unwrap();
    }

    fn heal(&self) {
        let _ = std::fs::remove_file(&self.rules);
    }

    async fn job(&self, id: &str) -> Value {
        common::job(&self.c, &self.base, id).await
    }

    async fn until(&self, id: &str, states: &[&str], within: Duration) -> Value {
        wait_states(&self.c, &self.base, id, states, within).await
    }

    async fn status(&self, r: reqwest::RequestBuilder) -> u16 {
        let r = r.send().await.unwrap();
        let status = r.status().as_u16();
        if status == 503 {
            assert!(
                r.headers().get("retry-after").is_some(),
                "503 without Retry-After"
            );
            let b: Value = r.json().await.unwrap();
            assert_eq!(b["error"]["code"], "unavailable", "{b}");
        }
        status
    }

    async fn healthz(&self) -> (u16, Value) {
        let r = self.c.get(self.url("/healthz")).send().await.unwrap();
        (r.status().as_u16(), r.json().await.unwrap())
    }

    /// A succeeded job must serve its image.
    async fn assert_honest(&self, id: &str, context: &str) {
        let j = self.job(id).await;
        if j["state"] == "succeeded" {
            let r = self
                .c
                .get(self.url(&format!("/v1/jobs/{id}/frame")))
                .send()
                .await
                .unwrap();
            assert_eq!(
                r.status(),
                200,
                "{context}: succeeded without its image: {j}"
            );
        }
    }
}

fn small(name: &str) -> Value {
    common::sphere_scene(name, 24, 24, "reference", 1, 1)
}

/// Renders for minutes, but shows a first frame within a second or two.
fn long(name: &str) -> Value {
    common::sphere_scene(name, 128, 128, "progressive", 4096, 2)
}

/// Waits until a running job has published a frame (so a cancel leaves one to store).
async fn until_first_frame(s: &Srv, id: &str) {
    let deadline = Instant::now() + Duration::from_secs(60);
    while s.job(id).await["progress"].is_null() {
        assert!(Instant::now() < deadline, "no first frame");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// One write failing: every operation a client has, then the fault cleared.
async fn one_write_fails(s: &Srv, write: Write) {
    let w = write.name();
    let done = submit(&s.c, &s.base, &small("done")).await;
    s.until(&done, &["succeeded"], Duration::from_secs(30))
        .await;
    let running = submit(&s.c, &s.base, &long("running")).await;
    s.until(&running, &["running"], Duration::from_secs(30))
        .await;
    until_first_frame(s, &running).await;
    let waiting = submit(&s.c, &s.base, &small("waiting")).await;
    // Its late files (written just after `done`) are on disk before the fault.
    s.assert_honest(&done, w).await;
    tokio::time::sleep(Duration::from_millis(200)).await;

    s.fail(w);
    let post =
        s.c.post(s.url("/v1/jobs"))
            .header("content-type", "application/json")
            .body(small("new").to_string());
    let new = match s.status(post).await {
        201 => Some(s.c.get(s.url("/v1/jobs?limit=1")).send().await.unwrap()),
        503 => None,
        other => panic!("{w}: POST answered {other}"),
    };
    let new = match new {
        Some(r) => Some(
            r.json::<Value>().await.unwrap()["jobs"][0]["id"]
                .as_str()
                .unwrap()
                .to_owned(),
        ),
        None => None,
    };
    let cancel = |id: &str| s.c.post(s.url(&format!("/v1/jobs/{id}/cancel")));
    let waiting_cancel = s.status(cancel(&waiting)).await;
    let delete = s
        .status(s.c.delete(s.url(&format!("/v1/jobs/{done}"))))
        .await;
    let running_cancel = s.status(cancel(&running)).await;
    for (what, status) in [
        ("cancel (queued)", waiting_cancel),
        ("DELETE", delete),
        ("cancel (running)", running_cancel),
    ] {
        assert!(
            [202, 204, 503].contains(&status),
            "{w}: {what} answered {status}"
        );
    }

    // While the write fails: the fault is reported, and no job lies about its state.
    // At least 1.5 s; longer if the fault is not reported yet (a worker reaches the
    // start write only once the cancelled render has ended, slower on a loaded machine).
    // On PostgreSQL a failing claim or reaper is not this node's store fault: the shared
    // database's health is what `/healthz`'s ping reports. On SQLite no heartbeat comes
    // while the fault lasts (they are 2 s apart with the default lease, and the running
    // job is cancelled at once, its end fenced by nothing: one node holds every lease).
    let shared = std::env::var("GLIMPSE_TEST_BACKEND").as_deref() == Ok("postgres");
    let unreported = match write {
        Write::Start | Write::Reap => shared,
        Write::Heartbeat => !shared,
        _ => false,
    };
    let mut reported = false;
    let until = Instant::now() + Duration::from_millis(1500);
    let give_up = Instant::now() + Duration::from_secs(15);
    while Instant::now() < until || (!reported && !unreported && Instant::now() < give_up) {
        let (status, h) = s.healthz().await;
        if status == 503 {
            assert_eq!(h["status"], "store_fault", "{w}: {h}");
            assert!(h["error"]["message"].as_str().unwrap().contains(w), "{h}");
            reported = true;
        }
        // The deleted job too: a DELETE whose record removal failed after its files were
        // removed must not leave it succeeded without its image.
        for id in [&running, &waiting, &done].into_iter().chain(&new) {
            s.assert_honest(id, w).await;
        }
        if delete == 204 {
            assert_eq!(s.job(&done).await["error"]["code"], "not_found", "{w}");
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(
        reported || unreported,
        "{w}: /healthz never reported the fault"
    );
    match write {
        Write::Start => {
            if let Some(new) = &new {
                assert_eq!(s.job(new).await["state"], "queued", "{w}");
            }
        }
        Write::Finish | Write::FinalImage => {
            // The render has ended; its end cannot be stored: still running, retried.
            assert_eq!(s.job(&running).await["state"], "running", "{w}");
        }
        _ => {}
    }

    // The write works again: no restart, every job ends as it was asked to.
    s.heal();
    let settle = Duration::from_secs(30);
    if running_cancel == 503 {
        assert_eq!(s.status(cancel(&running)).await, 202, "{w}");
    }
    if waiting_cancel == 503 {
        assert!(
            [202, 409].contains(&s.status(cancel(&waiting)).await),
            "{w}"
        );
    }
    s.until(&running, &["cancelled"], settle).await;
    // A cancelled job keeps its latest frame; but on PostgreSQL (2 s leases here) the
    // lease may run out while the heartbeat fails, and the reaper then ends the job
    // cancelled (as asked) with no frame stored.
    if !(shared && write == Write::Heartbeat) {
        let r =
            s.c.get(s.url(&format!("/v1/jobs/{running}/frame")))
                .send()
                .await;
        assert_eq!(r.unwrap().status(), 200, "{w}: the cancelled job's frame");
    }
    s.until(&waiting, &["cancelled", "succeeded"], settle).await;
    if let Some(new) = &new {
        s.until(new, &["succeeded"], settle).await;
    }
    for id in [&running, &waiting].into_iter().chain(&new) {
        s.assert_honest(id, w).await;
    }
    if delete == 503 {
        let r = s.c.delete(s.url(&format!("/v1/jobs/{done}"))).send().await;
        assert_eq!(r.unwrap().status(), 204, "{w}: DELETE after the fault");
    }
    // New work runs, and with it every kind of write succeeds again: healthy.
    let fresh = submit(&s.c, &s.base, &small("fresh")).await;
    s.until(&fresh, &["succeeded"], settle).await;
    s.assert_honest(&fresh, w).await;
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let (status, h) = s.healthz().await;
        if status == 200 {
            break;
        }
        assert!(Instant::now() < deadline, "{w}: {h}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    eprintln!(
        "{w}: POST {}, cancel queued {waiting_cancel}, DELETE {delete}, cancel running \
         {running_cancel}; settled",
        if new.is_some() { 201 } else { 503 }
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fault_at_any_write_ends_cleanly_and_work_resumes_without_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    let s = Srv {
        base: String::new(),
        port: free_port(),
        c: reqwest::Client::new(),
        rules: dir.path().join("faults"),
    };
    let s = Srv {
        base: format!("http://127.0.0.1:{}", s.port),
        ..s
    };
    let server = s.spawn(&data).await;
    let t = Instant::now();
    for write in Write::ALL {
        if matches!(write, Write::Recover | Write::Requeue) {
            continue; // start-up and shutdown: below
        }
        one_write_fails(&s, write).await;
    }
    eprintln!(
        "every write faulted in turn: {:.1} s",
        t.elapsed().as_secs_f64()
    );

    // A graceful shutdown that cannot requeue its running job, then (SQLite) a start-up
    // that cannot recover: the start-up refuses in one line naming the fault, and the
    // next one (space back) runs the job again. On PostgreSQL a start-up recovers
    // nothing (running jobs may be other nodes'): the job's lease expires and a reaper
    // requeues it (cluster.md).
    let running = submit(&s.c, &s.base, &long("interrupted")).await;
    s.until(&running, &["running"], Duration::from_secs(30))
        .await;
    s.fail(Write::Requeue.name());
    assert!(server.terminate().await.success());
    let database = match common::test_database(&data).await {
        Some(glimpse::service::store::Database::Postgres(url)) => {
            vec!["--database".to_owned(), url]
        }
        _ => Vec::new(),
    };
    if database.is_empty() {
        s.fail(Write::Recover.name());
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_glimpse"))
            .args([
                "serve",
                "--addr",
                &format!("127.0.0.1:{}", s.port),
                "--data",
            ])
            .arg(&data)
            .env("GLIMPSE_FAULTS", &s.rules)
            .env_remove("GLIMPSE_TOKEN")
            .output()
            .unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(Write::Recover.name()), "{err}");
    }
    s.heal();
    let _server = s.spawn(&data).await;
    // Running again, as its second attempt (on PostgreSQL the record says `running` with
    // the first attempt's stale lease until the reaper takes it back).
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let j = s.job(&running).await;
        if j["state"] == "running" && j["attempt"] == 2 {
            break;
        }
        assert!(Instant::now() < deadline, "not run again: {j}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let r =
        s.c.post(s.url(&format!("/v1/jobs/{running}/cancel")))
            .send()
            .await
            .unwrap();
    assert_eq!(r.status(), 202);
    s.until(&running, &["cancelled"], Duration::from_secs(10))
        .await;
}
