//! Many nodes on one PostgreSQL database (shared/spec/cluster.md, "What it must show"):
//! two API nodes that only serve and two worker processes, real processes on loopback,
//! sharing one job folder and a PostgreSQL server of this test's own (it is restarted
//! with `-m immediate`, which a server shared with other tests could not be).
//!
//! 6 jobs are submitted to node A and watched on node B; a worker is killed (`-9`)
//! mid-render and a third started; node A is killed; the database restarts. Every job
//! succeeds, the killed worker's job in its second attempt, and node B serves every final
//! image. Then a cancel sent to node B stops a render on a worker within 5 s.
//!
//! A stream on a node whose own worker loses its job's lease (the node paused with
//! SIGSTOP for longer than the lease while a worker node takes the job over) follows the
//! job to the new owner's frames and its `done`; that worker node serves its own
//! `/healthz` and `/metrics` (`--metrics-addr`).

mod common;

use common::{free_port, Proc};
use futures_util::StreamExt;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

const PG_BIN: &str = "/usr/lib/postgresql/15/bin";
/// Short enough that a killed worker's job is taken over in seconds; ten heartbeats of
/// 300 ms fit in it, so the database's restart (about a second) costs no lease.
const LEASE: &str = "3";

/// A PostgreSQL server of this test's own in a temporary folder, on a free port; run as
/// the `postgres` user when we are root (the server refuses root).
struct Postgres {
    dir: tempfile::TempDir,
    port: u16,
}

fn as_pg(args: &[&str]) -> Command {
    let root = Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| o.stdout.starts_with(b"0\n"));
    let mut c = if root {
        let mut c = Command::new("runuser");
        c.args(["-u", "postgres", "--"]);
        c.args(args);
        c
    } else {
        let mut c = Command::new(args[0]);
        c.args(&args[1..]);
        c
    };
    c.stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    c
}

impl Postgres {
    fn start() -> Self {
        if !Path::new(PG_BIN).join("initdb").exists() {
            // scripts/pg.sh installs the package where it is missing.
            common::pg_server_url();
        }
        let dir = tempfile::Builder::new()
            .prefix("glimpse-cluster-pg")
            .tempdir()
            .unwrap();
        let path = dir.path().to_str().unwrap().to_owned();
        let ok = Command::new("chmod").args(["777", &path]).status().unwrap();
        assert!(ok.success());
        let data = format!("{path}/data");
        let initdb = format!("{PG_BIN}/initdb");
        let st = as_pg(&[
            &initdb,
            "-D",
            &data,
            "-U",
            "postgres",
            "-A",
            "trust",
            "--no-sync",
        ])
        .status()
        .unwrap();
        assert!(st.success(), "initdb failed");
        let pg = Self {
            dir,
            port: free_port(),
        };
        pg.pg_ctl(&["start", "-w", "-t", "30"]);
        pg
    }

    fn pg_ctl(&self, args: &[&str]) {
        let path = self.dir.path().to_str().unwrap();
        let data = format!("{path}/data");
        let log = format!("{path}/server.log");
        let opts = format!(
            "-c listen_addresses=127.0.0.1 -p {} -c unix_socket_directories={path}",
            self.port
        );
        let pg_ctl = format!("{PG_BIN}/pg_ctl");
        let mut full = vec![pg_ctl.as_str(), "-D", &data, "-l", &log, "-o", &opts];
        full.extend_from_slice(args);
        let st = as_pg(&full).status().unwrap();
        assert!(st.success(), "pg_ctl {args:?} failed");
    }

    fn url(&self) -> String {
        format!("postgres://postgres@127.0.0.1:{}/postgres", self.port)
    }

    /// Crash-stop (no checkpoint: what a power cut leaves) and start again.
    fn restart_immediate(&self) {
        self.pg_ctl(&["stop", "-m", "immediate", "-w"]);
        self.pg_ctl(&["start", "-w", "-t", "30"]);
    }
}

impl Drop for Postgres {
    fn drop(&mut self) {
        let path = self.dir.path().to_str().unwrap();
        let data = format!("{path}/data");
        let pg_ctl = format!("{PG_BIN}/pg_ctl");
        let _ = as_pg(&[&pg_ctl, "-D", &data, "stop", "-m", "immediate", "-w"]).status();
    }
}

/// `glimpse ARGS` with its logs in `log`.
fn glimpse(args: &[&str], log: &Path) -> Proc {
    common::glimpse(args, log, "info")
}

struct Cluster {
    pg: Postgres,
    data: PathBuf,
    logs: tempfile::TempDir,
    c: reqwest::Client,
}

impl Cluster {
    /// An API node that only serves; waits until it answers.
    async fn api(&self, name: &str) -> (Proc, String) {
        let port = free_port();
        let addr = format!("127.0.0.1:{port}");
        let p = glimpse(
            &[
                "serve",
                "--addr",
                &addr,
                "--workers",
                "0",
                "--database",
                &self.pg.url(),
                "--data",
                self.data.to_str().unwrap(),
                "--lease",
                LEASE,
            ],
            &self.logs.path().join(format!("{name}.log")),
        );
        let base = format!("http://{addr}");
        common::wait_up(&self.c, &base, Duration::from_secs(30)).await;
        (p, base)
    }

    /// A worker node on one render thread.
    fn worker(&self, name: &str) -> Proc {
        glimpse(
            &[
                "worker",
                "--database",
                &self.pg.url(),
                "--data",
                self.data.to_str().unwrap(),
                "--threads",
                "1",
                "--name",
                name,
                "--lease",
                LEASE,
            ],
            &self.logs.path().join(format!("{name}.log")),
        )
    }

    fn log(&self, name: &str) -> String {
        std::fs::read_to_string(self.logs.path().join(format!("{name}.log"))).unwrap_or_default()
    }
}

fn scene(k: u64, w: u32, spp: u32, mode: &str) -> Value {
    common::sphere_scene(&format!("cluster-{k}"), w, w, mode, spp, k)
}

/// Polls `base` until `pred` holds for job `id`; its object. Fails after `within`.
async fn wait_job(
    c: &reqwest::Client,
    base: &str,
    id: &str,
    within: Duration,
    pred: impl Fn(&Value) -> bool,
) -> Value {
    let deadline = Instant::now() + within;
    loop {
        // The database may be restarting: a failed request is tried again.
        if let Ok(r) = c.get(format!("{base}/v1/jobs/{id}")).send().await {
            if let Ok(j) = r.json::<Value>().await {
                if pred(&j) {
                    return j;
                }
                assert!(Instant::now() < deadline, "job {id}: {j}");
            }
        }
        assert!(Instant::now() < deadline, "job {id}: no answer");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Reads a job's stream to its end: (text messages, binary frames).
async fn watch(url: String) -> (Vec<Value>, usize) {
    let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
    let (mut texts, mut frames) = (Vec::new(), 0);
    while let Ok(Some(m)) = tokio::time::timeout(Duration::from_secs(90), ws.next()).await {
        match m {
            Ok(Message::Text(t)) => texts.push(serde_json::from_str(&t).unwrap()),
            Ok(Message::Binary(b)) => {
                assert!(b.starts_with(b"\x89PNG"), "a frame is a PNG");
                frames += 1;
            }
            Ok(Message::Close(_)) | Err(_) => break,
            Ok(_) => {}
        }
    }
    (texts, frames)
}

/// The tests here run one at a time: each keeps both cores busy, and the first times
/// kills against renders.
static ONE_AT_A_TIME: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killed_workers_nodes_and_database_lose_no_job_and_a_cancel_crosses_nodes() {
    let _turn = ONE_AT_A_TIME.lock().await;
    let pg = Postgres::start();
    let data = tempfile::tempdir().unwrap();
    let cl = Cluster {
        pg,
        data: data.path().to_owned(),
        logs: tempfile::tempdir().unwrap(),
        c: reqwest::Client::new(),
    };
    let (node_a, a) = cl.api("node-a").await;
    let (_node_b, b) = cl.api("node-b").await;
    let w1 = cl.worker("w1");
    let _w2 = cl.worker("w2");

    // Six jobs of ~2 s each on one thread (0.3 s at 96 spp was too short to be caught
    // running), submitted to node A.
    let mut ids = Vec::new();
    for k in 0..6u64 {
        ids.push(common::submit(&cl.c, &a, &scene(k + 1, 128, 640, "progressive")).await);
    }
    // A watcher on node B follows the first job, whichever worker renders it.
    let ws_b = b.replace("http://", "ws://");
    let watcher = tokio::spawn(watch(format!("{ws_b}/v1/jobs/{}/stream", ids[0])));

    // Kill w1 in the middle of a render (a frame of it seen through node B).
    let deadline = Instant::now() + Duration::from_secs(30);
    let killed = 'found: loop {
        for id in &ids {
            let j = common::job(&cl.c, &b, id).await;
            // In its render (a relayed frame) and not about to end (no time left
            // known yet, or more than half a second), so that it cannot finish between
            // this look and the kill.
            let p = &j["progress"];
            let early = !p.is_null() && p["eta_ms"].as_u64().is_none_or(|ms| ms > 500);
            if j["worker"] == "w1" && j["state"] == "running" && early {
                break 'found id.clone();
            }
        }
        assert!(Instant::now() < deadline, "w1 never ran a job");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    w1.kill_hard();
    let _w3 = cl.worker("w3");
    node_a.kill_hard();
    cl.pg.restart_immediate();

    // Every job succeeds; node B serves each final image.
    for id in &ids {
        let j = wait_job(&cl.c, &b, id, Duration::from_secs(90), |j| {
            j["state"] != "queued" && j["state"] != "running"
        })
        .await;
        assert_eq!(j["state"], "succeeded", "{j}\nw3: {}", cl.log("w3"));
        if *id == killed {
            assert!(j["attempt"].as_u64() >= Some(2), "{j}");
            assert_ne!(j["worker"], "w1", "{j}");
        }
        let r =
            cl.c.get(format!("{b}/v1/jobs/{id}/frame"))
                .send()
                .await
                .unwrap();
        assert_eq!(r.status(), 200, "{id}");
        let png = r.bytes().await.unwrap();
        assert_eq!(image::load_from_memory(&png).unwrap().width(), 128);
    }
    let (texts, frames) = watcher.await.unwrap();
    assert!(frames >= 1, "the watcher on node B saw no frame: {texts:?}");
    let last = texts.last().unwrap();
    assert_eq!(last["type"], "done", "{texts:?}");
    assert_eq!(last["job"]["state"], "succeeded", "{texts:?}");

    // A cancel sent to node B reaches the worker rendering the job within 5 s.
    let long = common::submit(&cl.c, &b, &scene(99, 256, 4096, "reference")).await;
    let j = wait_job(&cl.c, &b, &long, Duration::from_secs(30), |j| {
        j["state"] == "running"
    })
    .await;
    let worker = j["worker"].as_str().unwrap().to_owned();
    let t0 = Instant::now();
    let r =
        cl.c.post(format!("{b}/v1/jobs/{long}/cancel"))
            .send()
            .await
            .unwrap();
    assert_eq!(r.status(), 202);
    let j = wait_job(&cl.c, &b, &long, Duration::from_secs(5), |j| {
        j["state"] == "cancelled"
    })
    .await;
    let took = t0.elapsed();
    assert!(took < Duration::from_secs(5), "cancel took {took:?}: {j}");
    assert!(
        cl.log(&worker).contains("cancel asked on another node"),
        "{}",
        cl.log(&worker)
    );
    eprintln!("cancel across nodes: {took:?}");
}

/// `kill -SIG pid`.
fn signal(p: &Proc, sig: &str) {
    let pid = p.0.id().to_string();
    let st = Command::new("kill").args([sig, &pid]).status().unwrap();
    assert!(st.success(), "kill {sig} {pid}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stream_follows_its_job_when_the_nodes_worker_loses_the_lease() {
    let _turn = ONE_AT_A_TIME.lock().await;
    let db = common::fresh_pg_database().await;
    let data = tempfile::tempdir().unwrap();
    let logs = tempfile::tempdir().unwrap();
    let c = reqwest::Client::new();
    let port = free_port();
    let addr = format!("127.0.0.1:{port}");
    let base = format!("http://{addr}");
    let data_dir = data.path().to_str().unwrap();
    let node = glimpse(
        &[
            "serve",
            "--addr",
            &addr,
            "--workers",
            "1",
            "--name",
            "node-a",
            "--database",
            &db,
            "--data",
            data_dir,
            "--lease",
            "1",
        ],
        &logs.path().join("node-a.log"),
    );
    let deadline = Instant::now() + Duration::from_secs(30);
    while c.get(format!("{base}/healthz")).send().await.is_err() {
        assert!(Instant::now() < deadline, "node A did not come up");
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    let id = common::submit(&c, &base, &scene(7, 128, 640, "progressive")).await;
    wait_job(&c, &base, &id, Duration::from_secs(30), |j| {
        j["state"] == "running" && j["worker"] == "node-a"
    })
    .await;
    let stream = tokio::spawn(watch(format!("ws://{addr}/v1/jobs/{id}/stream")));
    tokio::time::sleep(Duration::from_millis(300)).await;
    // Node A stalls for longer than its lease; a worker node's reaper takes the job
    // back and its worker claims it.
    signal(&node, "-STOP");
    let metrics_addr = format!("127.0.0.1:{}", free_port());
    let worker = glimpse(
        &[
            "worker",
            "--database",
            &db,
            "--data",
            data_dir,
            "--threads",
            "1",
            "--name",
            "w",
            "--lease",
            "1",
            "--metrics-addr",
            &metrics_addr,
        ],
        &logs.path().join("w.log"),
    );
    let log = || std::fs::read_to_string(logs.path().join("w.log")).unwrap_or_default();
    let deadline = Instant::now() + Duration::from_secs(30);
    while !log().contains("job started") {
        assert!(
            Instant::now() < deadline,
            "the worker never took the job: {}",
            log()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    signal(&node, "-CONT");

    let (texts, frames) = stream.await.unwrap();
    let last = texts.last().unwrap();
    assert_eq!(last["type"], "done", "{texts:?}");
    assert_eq!(last["job"]["state"], "succeeded", "{texts:?}");
    assert_eq!(last["job"]["worker"], "w", "{texts:?}");
    assert_eq!(last["job"]["attempt"], 2, "{texts:?}");
    // Then the new owner's frames: after a `state` of the second attempt (the stream
    // was on this node's worker's own channel) or relayed from the worker node (image
    // layer only: the stream had joined through the store, before the claim was live).
    let moved = texts
        .iter()
        .position(|m| {
            (m["type"] == "state" && m["job"]["attempt"] == 2)
                || (m["type"] == "frame" && m["layers"] == serde_json::json!(["image"]))
        })
        .unwrap_or_else(|| panic!("nothing of the second attempt: {texts:?}"));
    assert!(
        texts[moved..].iter().any(|m| m["type"] == "frame"),
        "no frame after the move: {texts:?}"
    );
    assert!(frames >= 2, "{frames} frames: {texts:?}");
    let node_log = std::fs::read_to_string(logs.path().join("node-a.log")).unwrap();
    assert!(node_log.contains("lease lost"), "{node_log}");
    // The worker node's own /healthz and /metrics (--metrics-addr), and nothing else.
    let w = format!("http://{metrics_addr}");
    let health = common::get_json(&c, &format!("{w}/healthz")).await;
    assert_eq!(health["database"], "postgres", "{health}");
    let r = c.get(format!("{w}/metrics")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    let text = r.text().await.unwrap();
    assert!(text.contains("glimpse_node{name=\"w\"} 1"), "{text}");
    assert!(text.contains("glimpse_claims_total 1"), "{text}");
    let r = c.get(format!("{w}/v1/jobs")).send().await.unwrap();
    assert_eq!(r.status(), 404);
    // The same Host rule as an API node's without a token (no DNS rebinding).
    let r = c
        .get(format!("{w}/metrics"))
        .header("Host", "attacker.example")
        .send()
        .await
        .unwrap();
    assert!(matches!(r.status().as_u16(), 403 | 421), "{}", r.status());
    // It stops on SIGTERM, its HTTP with it.
    assert!(worker.terminate().await.success());
    assert!(c.get(format!("{w}/healthz")).send().await.is_err());
}
