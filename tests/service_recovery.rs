//! The service recovers from faults by itself and says what is wrong, against the real
//! server binary:
//! - a claim whose COMMIT fails as on a full disk (SQLite rolls the transaction back by
//!   itself) leaves no connection stuck inside a transaction: once space returns, the
//!   queued jobs start, `/healthz` is 200 and new work is taken, without a restart; on a
//!   real full tmpfs where one can be mounted, and with the injected fault everywhere;
//! - a PostgreSQL outage (a TCP proxy in front of the test server, shut down mid-run) is
//!   answered within ~2 s with `503 database_unreachable`, not after 10 s as a full disk;
//! - a finished job whose files were removed outside the server, or whose folder became
//!   a regular file, answers `410 files_missing` for its frames and iterations, and the
//!   server logs it; `DELETE` forgets it with `204`, and `/healthz` stays `200` (one
//!   job's odd folder is no store fault);
//! - a corrupt database stops the start-up before anything says "listening on".

mod common;

use common::{free_port, submit, wait_state, Proc};
use futures_util::StreamExt;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn small(name: &str, seed: u64) -> Value {
    common::sphere_scene(name, 24, 24, "reference", 1, seed)
}

/// `glimpse serve` on SQLite in `data` with its log in `log`, `GLIMPSE_FAULTS=rules`.
async fn serve_sqlite(
    data: &Path,
    port: u16,
    log: &Path,
    rules: &Path,
    c: &reqwest::Client,
) -> Proc {
    let child = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .args(["serve", "--addr", &format!("127.0.0.1:{port}"), "--data"])
        .arg(data)
        .args(["--workers", "1"])
        .env("RUST_LOG", "info")
        .env("GLIMPSE_FAULTS", rules)
        .env_remove("GLIMPSE_TOKEN")
        .env_remove("GLIMPSE_LOG_FORMAT")
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(log).unwrap())
        .spawn()
        .unwrap();
    let p = Proc(child);
    wait_healthz_answers(c, port).await;
    p
}

async fn wait_healthz_answers(c: &reqwest::Client, port: u16) {
    let deadline = Instant::now() + Duration::from_secs(20);
    while c
        .get(format!("http://127.0.0.1:{port}/healthz"))
        .send()
        .await
        .is_err()
    {
        assert!(Instant::now() < deadline, "server did not come up");
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
}

async fn healthz(c: &reqwest::Client, base: &str) -> (u16, Value) {
    let r = c.get(format!("{base}/healthz")).send().await.unwrap();
    (r.status().as_u16(), r.json().await.unwrap())
}

/// Polls `/healthz` until it answers 200; fails after `within`.
async fn until_healthy(c: &reqwest::Client, base: &str, within: Duration) {
    let deadline = Instant::now() + within;
    loop {
        let (status, h) = healthz(c, base).await;
        if status == 200 {
            return;
        }
        assert!(Instant::now() < deadline, "/healthz still {status}: {h}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// The disk fills while jobs wait (the claims' COMMITs fail), then space returns: every
/// queued job starts and ends with its image, `/healthz` is 200 again, new work runs,
/// and no connection was ever left inside a transaction. `full` makes the disk full (and
/// says whether it is a real one), `free` gives the space back.
async fn claims_resume_after_a_full_disk(
    data: &Path,
    rules: &Path,
    full: impl Fn(),
    free: impl Fn(),
) {
    let port = free_port();
    let base = format!("http://127.0.0.1:{port}");
    let c = reqwest::Client::new();
    let log = data.with_extension("log");
    let _server = serve_sqlite(data, port, &log, rules, &c).await;
    let first = submit(&c, &base, &small("first", 1)).await;
    wait_state(&c, &base, &first, "succeeded", Duration::from_secs(30)).await;

    // Five jobs accepted, then the disk is full before the worker can start them (a real
    // full disk may refuse some submissions: those answer 503).
    full();
    let mut queued = Vec::new();
    for k in 0..5 {
        let r = c
            .post(format!("{base}/v1/jobs"))
            .json(&small(&format!("queued-{k}"), 10 + k))
            .send()
            .await
            .unwrap();
        match r.status().as_u16() {
            201 => queued.push(
                r.json::<Value>().await.unwrap()["id"]
                    .as_str()
                    .unwrap()
                    .to_owned(),
            ),
            503 => {}
            s => panic!("POST while the disk is full answered {s}"),
        }
    }
    // Several claims fail meanwhile (one a second).
    tokio::time::sleep(Duration::from_secs(4)).await;
    let (status, h) = healthz(&c, &base).await;
    assert_eq!(status, 503, "{h}");
    assert_eq!(h["status"], "store_fault", "{h}");

    // Space returns: no restart.
    free();
    let t = Instant::now();
    for id in &queued {
        wait_state(&c, &base, id, "succeeded", Duration::from_secs(30)).await;
        let r = c
            .get(format!("{base}/v1/jobs/{id}/frame"))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200, "job {id}'s image");
    }
    until_healthy(&c, &base, Duration::from_secs(10)).await;
    let after = submit(&c, &base, &small("after", 99)).await;
    wait_state(&c, &base, &after, "succeeded", Duration::from_secs(30)).await;
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(
        !text.contains("non-zero transaction depth"),
        "a connection was left inside a transaction:\n{text}"
    );
    eprintln!(
        "{} queued jobs done and healthy {:.1} s after space returned",
        queued.len(),
        t.elapsed().as_secs_f64()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_claim_whose_commit_fails_leaves_no_connection_stuck() {
    let dir = tempfile::tempdir().unwrap();
    let rules = dir.path().join("faults");
    let data = dir.path().join("data");
    claims_resume_after_a_full_disk(
        &data,
        &rules,
        || std::fs::write(&rules, "store.start").unwrap(),
        || std::fs::remove_file(&rules).unwrap(),
    )
    .await;
}

/// The probe's sequence on a real full filesystem (a 20 MB tmpfs), where one can be
/// mounted: five jobs wait behind a long one; the disk is filled but for room for the long
/// job's final image and record, so its other layers (written after `done`) fill the rest
/// and the next claim's COMMIT meets a full disk, as SQLite sees it. Where no tmpfs can be
/// mounted, the injected fault instead, so the test never passes without checking.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn claims_resume_when_a_real_full_disk_gets_space_back() {
    let dir = tempfile::tempdir().unwrap();
    let rules = dir.path().join("faults");
    let Some(fs) = common::Tmpfs::mount(&dir.path().join("mnt"), "20m") else {
        eprintln!("cannot mount a tmpfs here (needs root): the injected fault instead");
        claims_resume_after_a_full_disk(
            &dir.path().join("data"),
            &rules,
            || std::fs::write(&rules, "store.start").unwrap(),
            || std::fs::remove_file(&rules).unwrap(),
        )
        .await;
        return;
    };
    let data = fs.0.join("data");
    let port = free_port();
    let base = format!("http://127.0.0.1:{port}");
    let c = reqwest::Client::new();
    let log = dir.path().join("server.log");
    let _server = serve_sqlite(&data, port, &log, &rules, &c).await;
    let big = submit(
        &c,
        &base,
        &common::sphere_scene("big", 512, 512, "progressive", 4096, 3),
    )
    .await;
    let frame = format!("{base}/v1/jobs/{big}/frame");
    let deadline = Instant::now() + Duration::from_secs(60);
    let (png, exr) = loop {
        let r = c.get(&frame).send().await.unwrap();
        if r.status() == 200 {
            let png = r.bytes().await.unwrap().len() as u64;
            let r = c.get(format!("{frame}?format=exr")).send().await.unwrap();
            break (png, r.bytes().await.unwrap().len() as u64);
        }
        assert!(Instant::now() < deadline, "no first frame");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let room = png + (256 << 10);
    assert!(exr > 2 * room, "the EXR ({exr} B) must not fit in {room} B");
    let mut queued = Vec::new();
    for k in 0..5 {
        queued.push(submit(&c, &base, &small(&format!("queued-{k}"), 10 + k)).await);
    }
    let filler = fs.0.join("filler");
    common::fill(&filler);
    let f = std::fs::OpenOptions::new()
        .write(true)
        .open(&filler)
        .unwrap();
    f.set_len(f.metadata().unwrap().len().saturating_sub(room))
        .unwrap();
    drop(f);
    let r = c
        .post(format!("{base}/v1/jobs/{big}/cancel"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 202);
    wait_state(&c, &base, &big, "cancelled", Duration::from_secs(30)).await;
    // The claims fail on the full disk for a few seconds.
    tokio::time::sleep(Duration::from_secs(4)).await;
    let (status, h) = healthz(&c, &base).await;
    assert_eq!(status, 503, "{h}");
    for id in &queued {
        assert_eq!(common::job(&c, &base, id).await["state"], "queued");
    }

    // The long job's DELETE and the filler free the space: no restart.
    std::fs::remove_file(&filler).unwrap();
    let r = c
        .delete(format!("{base}/v1/jobs/{big}"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204);
    let t = Instant::now();
    for id in &queued {
        wait_state(&c, &base, id, "succeeded", Duration::from_secs(30)).await;
    }
    until_healthy(&c, &base, Duration::from_secs(10)).await;
    let after = submit(&c, &base, &small("after", 99)).await;
    wait_state(&c, &base, &after, "succeeded", Duration::from_secs(30)).await;
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(
        !text.contains("non-zero transaction depth"),
        "a connection was left inside a transaction:\n{text}"
    );
    let claims_failed = text
        .lines()
        .filter(|l| l.contains("claiming a job") && l.contains("full"))
        .count();
    eprintln!(
        "real full disk: {claims_failed} claims failed on it; 5 queued jobs done and healthy \
         {:.1} s after space returned",
        t.elapsed().as_secs_f64()
    );
}

/// A TCP proxy on loopback in front of the test's PostgreSQL server: shutting it down
/// cuts every connection and refuses new ones, as a database that went away.
struct Proxy {
    port: u16,
    tasks: std::sync::Arc<std::sync::Mutex<Vec<tokio::task::JoinHandle<()>>>>,
    accept: tokio::task::JoinHandle<()>,
}

impl Proxy {
    /// Listens on `port` (0: any) and forwards each connection to `upstream`.
    async fn start(port: u16, upstream: String) -> Self {
        let listener = tokio::net::TcpListener::bind(("127.0.0.1", port))
            .await
            .unwrap();
        let port = listener.local_addr().unwrap().port();
        let tasks = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let tasks2 = std::sync::Arc::clone(&tasks);
        let accept = tokio::spawn(async move {
            while let Ok((mut down, _)) = listener.accept().await {
                let upstream = upstream.clone();
                let t = tokio::spawn(async move {
                    if let Ok(mut up) = tokio::net::TcpStream::connect(&upstream).await {
                        let _ = tokio::io::copy_bidirectional(&mut down, &mut up).await;
                    }
                });
                tasks2.lock().unwrap().push(t);
            }
        });
        Self {
            port,
            tasks,
            accept,
        }
    }

    /// Stops listening and drops every forwarded connection.
    fn shut(self) -> u16 {
        self.accept.abort();
        for t in self.tasks.lock().unwrap().drain(..) {
            t.abort();
        }
        self.port
    }
}

/// `url` with its `host:port` replaced by the proxy's, and that `host:port`.
fn through_proxy(url: &str, port: u16) -> (String, String) {
    let (scheme, rest) = url.split_once("://").unwrap();
    let (user, rest) = match rest.split_once('@') {
        Some((u, r)) => (format!("{u}@"), r),
        None => (String::new(), rest),
    };
    let end = rest.find(['/', '?']).unwrap_or(rest.len());
    let host = &rest[..end];
    let upstream = if host.contains(':') {
        host.to_owned()
    } else {
        format!("{host}:5432")
    };
    (
        format!("{scheme}://{user}127.0.0.1:{port}{}", &rest[end..]),
        upstream,
    )
}

/// Sends `req`, returning the status, the body and how long the answer took.
async fn timed(req: reqwest::RequestBuilder) -> (u16, Value, Duration) {
    let t = Instant::now();
    let r = req.send().await.unwrap();
    let status = r.status().as_u16();
    let body = r.json().await.unwrap_or(Value::Null);
    (status, body, t.elapsed())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_database_outage_is_answered_at_once_and_named() {
    let url = common::fresh_pg_database().await;
    let (_, upstream) = through_proxy(&url, 0);
    let proxy = Proxy::start(0, upstream.clone()).await;
    let (proxied, _) = through_proxy(&url, proxy.port);
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("server.log");
    let port = free_port();
    let base = format!("http://127.0.0.1:{port}");
    let c = reqwest::Client::new();
    let _server = common::glimpse(
        &[
            "serve",
            "--addr",
            &format!("127.0.0.1:{port}"),
            "--data",
            dir.path().join("data").to_str().unwrap(),
            "--database",
            &proxied,
        ],
        &log,
        "info",
    );
    wait_healthz_answers(&c, port).await;
    let done = submit(&c, &base, &small("before", 1)).await;
    wait_state(&c, &base, &done, "succeeded", Duration::from_secs(30)).await;

    // The database goes away.
    let proxy_port = proxy.shut();
    let slowest = Duration::from_millis(2500);
    let post = c.post(format!("{base}/v1/jobs")).json(&small("during", 2));
    let get = c.get(format!("{base}/v1/jobs/{done}"));
    let list = c.get(format!("{base}/v1/jobs"));
    for (what, req) in [("POST", post), ("GET", get), ("list", list)] {
        let (status, body, took) = timed(req).await;
        assert_eq!(status, 503, "{what}: {body}");
        assert_eq!(
            body["error"]["code"], "database_unreachable",
            "{what}: {body}"
        );
        let message = body["error"]["message"].as_str().unwrap();
        assert!(message.contains("cannot be reached"), "{what}: {message}");
        assert!(!message.contains("disk"), "{what}: {message}");
        assert!(took < slowest, "{what} took {took:?}");
        eprintln!("{what} with the database down: 503 in {took:?}");
    }
    let (status, h, took) = timed(c.get(format!("{base}/healthz"))).await;
    assert_eq!(status, 503, "{h}");
    assert_eq!(h["status"], "database_unreachable", "{h}");
    assert!(took < slowest, "/healthz took {took:?}");

    // It comes back: so does the node, by itself.
    let _proxy = Proxy::start(proxy_port, upstream).await;
    until_healthy(&c, &base, Duration::from_secs(15)).await;
    let after = submit(&c, &base, &small("after", 3)).await;
    wait_state(&c, &base, &after, "succeeded", Duration::from_secs(30)).await;
}

/// What became of a finished job's folder behind the server's back.
#[derive(Clone, Copy, PartialEq)]
enum Gone {
    Removed,
    /// A regular file where the folder was.
    FileInstead,
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_whose_files_were_removed_says_so() {
    files_gone(Gone::Removed).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_file_where_a_jobs_folder_was_is_its_files_gone_not_a_store_fault() {
    files_gone(Gone::FileInstead).await;
}

async fn files_gone(how: Gone) {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    let log = dir.path().join("server.log");
    let port = free_port();
    let base = format!("http://127.0.0.1:{port}");
    let c = reqwest::Client::new();
    let _server = common::spawn(&data, port, Some(&log), &["--workers", "1"], &[], &c).await;
    let id = submit(
        &c,
        &base,
        &common::sphere_scene("gone", 32, 32, "progressive", 4, 5),
    )
    .await;
    wait_state(&c, &base, &id, "succeeded", Duration::from_secs(30)).await;
    // Its late files land, then the whole folder goes behind the server's back.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let folder = data.join("jobs").join(&id);
    let image = find(&folder, "image.png").expect("the job's image");
    std::fs::remove_dir_all(&folder).unwrap();
    if how == Gone::FileInstead {
        std::fs::write(&folder, b"not a folder").unwrap();
    }

    // The record stays as it is (its statistics are true); its images say they are gone.
    let j = common::job(&c, &base, &id).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    let iteration = j["progress"]["iteration"].as_u64().unwrap();
    for path in [
        format!("/v1/jobs/{id}/frame"),
        format!("/v1/jobs/{id}/frame?layer=samples"),
        format!("/v1/jobs/{id}/frame?format=exr"),
        format!("/v1/jobs/{id}/frame?iteration={iteration}"),
        format!("/v1/jobs/{id}/iterations"),
    ] {
        let r = c.get(format!("{base}{path}")).send().await.unwrap();
        assert_eq!(r.status(), 410, "{path}");
        let b: Value = r.json().await.unwrap();
        assert_eq!(b["error"]["code"], "files_missing", "{path}: {b}");
        let message = b["error"]["message"].as_str().unwrap();
        assert!(
            message.contains("missing") && message.contains(&id),
            "{message}"
        );
        assert!(
            !message.contains(data.to_str().unwrap()),
            "the server's path: {message}"
        );
    }
    // Its stream says so too, in the same shape.
    let (mut ws, _) =
        tokio_tungstenite::connect_async(format!("ws://127.0.0.1:{port}/v1/jobs/{id}/stream"))
            .await
            .unwrap();
    let error = loop {
        let m = tokio::time::timeout(Duration::from_secs(10), ws.next())
            .await
            .expect("the stream answers")
            .expect("the stream sends a message")
            .unwrap();
        if let tokio_tungstenite::tungstenite::Message::Text(t) = m {
            let v: Value = serde_json::from_str(&t).unwrap();
            if v["type"] != "state" {
                break v;
            }
        }
    };
    assert_eq!(error["type"], "error", "{error}");
    assert_eq!(error["error"]["code"], "files_missing", "{error}");
    // Logged, naming the job and the missing file.
    let text = std::fs::read_to_string(&log).unwrap();
    let line = text
        .lines()
        .find(|l| l.contains("files are missing"))
        .unwrap_or_else(|| panic!("nothing logged:\n{text}"));
    assert!(line.contains("WARN"), "{line}");
    assert!(line.contains(&id), "{line}");
    assert!(line.contains(&image.display().to_string()), "{line}");
    // Reading it never removed its record; DELETE does, with what stands in its folder's
    // place, and none of it is a fault of the store.
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(common::job(&c, &base, &id).await["state"], "succeeded");
    assert_eq!(healthz(&c, &base).await.0, 200);
    common::delete(&c, &base, &id).await;
    assert!(!folder.exists());
    let r = c.get(format!("{base}/v1/jobs/{id}")).send().await.unwrap();
    assert_eq!(r.status(), 404);
    let (status, h) = healthz(&c, &base).await;
    assert_eq!(status, 200, "{h}");
}

/// The file `name` in `dir` or below it (on a shared database a job's files are in its
/// attempt's folder).
fn find(dir: &Path, name: &str) -> Option<PathBuf> {
    for e in std::fs::read_dir(dir).ok()?.flatten() {
        let p = e.path();
        if p.is_dir() {
            if let Some(f) = find(&p, name) {
                return Some(f);
            }
        } else if e.file_name() == name {
            return Some(p);
        }
    }
    None
}

#[test]
fn a_corrupt_database_stops_the_start_before_it_says_listening() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    std::fs::write(data.join("glimpse.db"), vec![0x5Au8; 64 * 1024]).unwrap();
    let port = free_port();
    let out = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .args(["serve", "--addr", &format!("127.0.0.1:{port}"), "--data"])
        .arg(&data)
        .env("RUST_LOG", "info")
        .env_remove("GLIMPSE_TOKEN")
        .env_remove("GLIMPSE_LOG_FORMAT")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("cannot open the job store"), "{err}");
    assert!(!err.contains("listening on"), "said it listened:\n{err}");
    // Nothing listens either.
    assert!(std::net::TcpStream::connect(("127.0.0.1", port)).is_err());

    // A worker whose database cannot be reached does not open its metrics port first.
    let closed = free_port();
    let metrics = free_port();
    let out = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .args([
            "worker",
            "--database",
            &format!("postgres://glimpse@127.0.0.1:{closed}/jobs"),
            "--metrics-addr",
            &format!("127.0.0.1:{metrics}"),
            "--data",
        ])
        .arg(&data)
        .env("RUST_LOG", "info")
        .env_remove("GLIMPSE_LOG_FORMAT")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("cannot open the job store"), "{err}");
    assert!(!err.contains("/healthz and /metrics on"), "{err}");
}
