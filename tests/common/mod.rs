//! Helpers shared by the tests that run the real `glimpse` binary as a server process
//! (durability, graceful shutdown, load): a free loopback port, the process handle that
//! kills the server if a test fails, SIGTERM, and start-up that waits for `/healthz`; the
//! service tests' scene and JSON reads; and what the command-line tests share: a small lit
//! scene and the statistics fields.
#![allow(dead_code)] // each test file uses a different subset

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

pub fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().port()
}

/// The server process; killed (SIGKILL) if a test fails before stopping it.
pub struct Proc(pub Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Proc {
    /// SIGTERM (graceful shutdown, as a service manager would), then the exit status.
    /// std cannot send signals; the `kill` command can.
    pub async fn terminate(mut self) -> std::process::ExitStatus {
        let pid = self.0.id().to_string();
        let sent = Command::new("kill").args(["-TERM", &pid]).status().unwrap();
        assert!(sent.success(), "kill -TERM {pid} failed");
        let deadline = Instant::now() + Duration::from_secs(15);
        loop {
            if let Some(st) = self.0.try_wait().unwrap() {
                return st;
            }
            assert!(Instant::now() < deadline, "server did not stop on SIGTERM");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// SIGKILL: no shutdown code runs.
    pub fn kill_hard(mut self) {
        self.0.kill().unwrap();
        self.0.wait().unwrap();
    }
}

/// `glimpse ARGS` (any subcommand: a cluster test's API and worker nodes), its logs at
/// `rust_log` level in `log`; it does not wait for anything.
pub fn glimpse(args: &[&str], log: &Path, rust_log: &str) -> Proc {
    let child = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .args(args)
        .env("RUST_LOG", rust_log)
        .env_remove("GLIMPSE_TOKEN")
        .env_remove("GLIMPSE_LOG_FORMAT")
        .stdout(Stdio::null())
        .stderr(Stdio::from(std::fs::File::create(log).unwrap()))
        .spawn()
        .unwrap();
    Proc(child)
}

/// Starts `glimpse serve` on `port` with `--data data` and `extra` flags; stderr (the logs)
/// goes to `log` if given. Waits until `/healthz` answers.
pub async fn spawn(
    data: &Path,
    port: u16,
    log: Option<&Path>,
    extra: &[&str],
    env: &[(&str, &str)],
    client: &reqwest::Client,
) -> Proc {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_glimpse"));
    cmd.args(["serve", "--addr", &format!("127.0.0.1:{port}"), "--data"])
        .arg(data)
        .args(extra)
        .args(
            test_database(data)
                .await
                .map(|db| match db {
                    // A short lease: a job whose server was killed is claimed again
                    // after it expires (the embedded store recovers at start-up).
                    glimpse::service::store::Database::Postgres(url) => {
                        vec![
                            "--database".to_owned(),
                            url,
                            "--lease".to_owned(),
                            "2".to_owned(),
                        ]
                    }
                    glimpse::service::store::Database::Sqlite(_) => Vec::new(),
                })
                .unwrap_or_default(),
        )
        .env("RUST_LOG", if log.is_some() { "info" } else { "warn" })
        .env_remove("GLIMPSE_LOG_FORMAT")
        .env_remove("GLIMPSE_TOKEN")
        .stdout(Stdio::null())
        .stderr(match log {
            Some(p) => Stdio::from(std::fs::File::create(p).unwrap()),
            None => Stdio::null(),
        });
    for (k, v) in env {
        cmd.env(k, v);
    }
    let p = Proc(cmd.spawn().unwrap());
    wait_up(
        client,
        &format!("http://127.0.0.1:{port}"),
        Duration::from_secs(20),
    )
    .await;
    p
}

/// Waits until the server at `base` answers `/healthz` (any status), at most `within`.
pub async fn wait_up(client: &reqwest::Client, base: &str, within: Duration) {
    let deadline = Instant::now() + within;
    while client.get(format!("{base}/healthz")).send().await.is_err() {
        assert!(Instant::now() < deadline, "{base} did not come up");
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
}

/// `POST /v1/jobs` with `scene`; asserts 201 and returns the job id.
pub async fn submit(c: &reqwest::Client, base: &str, scene: &serde_json::Value) -> String {
    let r = c
        .post(format!("{base}/v1/jobs"))
        .json(scene)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201, "submission refused");
    r.json::<serde_json::Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned()
}

/// `DELETE /v1/jobs/{id}`; asserts `204`.
pub async fn delete(c: &reqwest::Client, base: &str, id: &str) {
    let r = c
        .delete(format!("{base}/v1/jobs/{id}"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204, "DELETE of job {id}");
}

/// `GET /v1/jobs/{id}` as JSON.
pub async fn job(c: &reqwest::Client, base: &str, id: &str) -> serde_json::Value {
    get_json(c, &format!("{base}/v1/jobs/{id}")).await
}

/// GET `url` and its body as JSON (panics on a transport error or a non-JSON body).
pub async fn get_json(c: &reqwest::Client, url: &str) -> serde_json::Value {
    c.get(url).send().await.unwrap().json().await.unwrap()
}

/// The service tests' scene: a diffuse sphere on a checker floor under a point light and a
/// sky, `w`×`h` pixels. Cheap at small sizes; `spp` sets the cost of a job.
pub fn sphere_scene(
    name: &str,
    w: u32,
    h: u32,
    mode: &str,
    spp: u32,
    seed: u64,
) -> serde_json::Value {
    serde_json::json!({
        "version": 1, "name": name,
        "image": { "width": w, "height": h },
        "camera": { "position": [0, 0, -4], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_y": 40 },
        "materials": {
            "white": { "type": "diffuse", "albedo": [0.8, 0.8, 0.8] },
            "floor": { "type": "diffuse", "texture": { "type": "checker", "scale": 0.5,
                       "a": [0.9, 0.9, 0.9], "b": [0.1, 0.1, 0.1] } }
        },
        "objects": [
            { "type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "white" },
            { "type": "quad", "corner": [-5, -1, -5], "edge_u": [0, 0, 10], "edge_v": [10, 0, 0],
              "material": "floor" }
        ],
        "lights": [
            { "type": "point", "position": [2, 3, -2], "intensity": [20, 20, 20] },
            { "type": "environment", "radiance": [0.3, 0.3, 0.4] }
        ],
        "render": { "mode": mode, "samples_per_pixel": spp, "max_bounces": 2, "seed": seed },
        "progressive": { "t0": 0.5, "initial_rate": 0.02, "force_loop": true }
    })
}

/// Polls the job until its state is `state`; fails after `within`.
pub async fn wait_state(c: &reqwest::Client, base: &str, id: &str, state: &str, within: Duration) {
    wait_states(c, base, id, &[state], within).await;
}

/// Polls the job until its state is one of `states`; its object. Fails after `within`.
pub async fn wait_states(
    c: &reqwest::Client,
    base: &str,
    id: &str,
    states: &[&str],
    within: Duration,
) -> serde_json::Value {
    let deadline = Instant::now() + within;
    loop {
        let j = job(c, base, id).await;
        if states.iter().any(|s| j["state"] == *s) {
            return j;
        }
        assert!(
            Instant::now() < deadline,
            "job {id} never reached {states:?}: {j}"
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

/// A small lit scene with a texture edge, a silhouette and a shadow (40×30, 4 spp): cheap,
/// and something for the progressive loop to refine (forced: its paths are so short that
/// a render would otherwise trace it whole, `reference_cheaper`).
pub const LIT_SCENE: &str = r#"{
  "version": 1, "name": "tiny",
  "image": { "width": 40, "height": 30 },
  "camera": { "position": [0, 1, 4], "look_at": [0, 0.5, 0], "fov_y": 45 },
  "materials": {
    "floor": { "type": "diffuse", "texture": { "type": "checker", "scale": 0.5,
               "a": [0.8, 0.8, 0.8], "b": [0.1, 0.1, 0.1] } },
    "ball": { "type": "diffuse", "albedo": [0.7, 0.3, 0.2] },
    "lamp": { "type": "emissive", "radiance": [8, 8, 8] }
  },
  "objects": [
    { "type": "quad", "corner": [-3, 0, 3], "edge_u": [6, 0, 0], "edge_v": [0, 0, -6],
      "material": "floor" },
    { "type": "sphere", "center": [0, 0.5, 0], "radius": 0.5, "material": "ball" },
    { "type": "quad", "corner": [-0.5, 2.5, -0.5], "edge_u": [1, 0, 0], "edge_v": [0, 0, 1],
      "material": "lamp" }
  ],
  "render": { "mode": "progressive", "samples_per_pixel": 4, "max_bounces": 2, "seed": 3 },
  "progressive": { "force_loop": true }
}"#;

/// The fields every statistics object holds (cli.md; a job's `stats` is the same object).
pub const STATS_FIELDS: [&str; 11] = [
    "mode",
    "width",
    "height",
    "iterations",
    "pixels_traced",
    "pixel_fraction",
    "total_ms",
    "trace_ms",
    "metric_ms",
    "triangulate_ms",
    "final_mean_distance",
];

/// The PostgreSQL server the tests use: `GLIMPSE_TEST_DATABASE_URL`, or else the
/// throwaway one `scripts/pg.sh` starts for this checkout (started here if it is not
/// running: no test is skipped for want of a database).
pub fn pg_server_url() -> String {
    if let Ok(url) = std::env::var("GLIMPSE_TEST_DATABASE_URL") {
        if !url.trim().is_empty() {
            return url;
        }
    }
    let out = Command::new("bash")
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/pg.sh"))
        .arg("ensure")
        .stderr(Stdio::inherit())
        .output()
        .expect("cannot run scripts/pg.sh");
    assert!(out.status.success(), "scripts/pg.sh ensure failed");
    String::from_utf8(out.stdout).unwrap().trim().to_owned()
}

/// A new, empty database on [`pg_server_url`]'s server; its URL.
pub async fn fresh_pg_database() -> String {
    use sqlx::Connection;
    let server = pg_server_url();
    let name = format!("glimpse_test_{}", uuid::Uuid::now_v7().simple());
    let mut conn = sqlx::PgConnection::connect(&server)
        .await
        .unwrap_or_else(|e| panic!("cannot reach the test database server: {e}"));
    sqlx::query(&format!("CREATE DATABASE {name}"))
        .execute(&mut conn)
        .await
        .unwrap();
    let (base, query) = server.split_once('?').unwrap_or((&server, ""));
    let root = base.rsplit_once('/').map_or(base, |(r, _)| r);
    if query.is_empty() {
        format!("{root}/{name}")
    } else {
        format!("{root}/{name}?{query}")
    }
}

/// The store the in-process service tests run on: SQLite in their data folder (the
/// default), or with `GLIMPSE_TEST_BACKEND=postgres` a database of its own on the test
/// server, kept for that folder (a restart on the same folder finds the same jobs).
pub async fn test_database(dir: &Path) -> Option<glimpse::service::store::Database> {
    if std::env::var("GLIMPSE_TEST_BACKEND").as_deref() != Ok("postgres") {
        return None;
    }
    let marker = dir.join("test-database-url");
    let url = match std::fs::read_to_string(&marker) {
        Ok(url) => url,
        Err(_) => {
            let url = fresh_pg_database().await;
            std::fs::write(&marker, &url).unwrap();
            url
        }
    };
    Some(glimpse::service::store::Database::Postgres(url))
}

/// Renders `scene` in reference mode through the real binary with `args` (e.g. `--spp`,
/// `--size`), and returns the linear EXR it wrote: pixels row-major and the size.
pub fn render_exr(scene: &Path, args: &[&str]) -> (Vec<[f32; 3]>, u32, u32) {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("out.exr");
    let out = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .arg("render")
        .arg(scene)
        .args(["--mode", "reference"])
        .args(args)
        .arg("--output")
        .arg(dir.path().join("out.png"))
        .arg("--exr")
        .arg(&exr)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    read_exr(&exr)
}

/// A linear EXR's pixels (row-major) and size.
pub fn read_exr(path: &Path) -> (Vec<[f32; 3]>, u32, u32) {
    let img = image::open(path).unwrap().into_rgb32f();
    let (w, h) = img.dimensions();
    (img.pixels().map(|p| p.0).collect(), w, h)
}

/// A zip of entries (name, data, unix mode); `deflate` packs them (else stored).
pub fn zip(entries: &[(&str, Vec<u8>, u32)], deflate: bool) -> Vec<u8> {
    let (mut out, mut dir) = (Vec::new(), Vec::new());
    for (name, data, mode) in entries {
        let packed = if deflate {
            miniz_oxide::deflate::compress_to_vec(data, 6)
        } else {
            data.clone()
        };
        let method: u16 = if deflate { 8 } else { 0 };
        let at = out.len() as u32;
        let head = |v: &mut Vec<u8>, central: bool| {
            v.extend(if central {
                [0x50, 0x4b, 0x01, 0x02]
            } else {
                [0x50, 0x4b, 0x03, 0x04]
            });
            if central {
                v.extend([20, 3]);
            }
            v.extend([20, 0, 0, 0]);
            v.extend(method.to_le_bytes());
            v.extend([0, 0, 0, 0, 0, 0, 0, 0]); // time, date, crc
            v.extend((packed.len() as u32).to_le_bytes());
            v.extend((data.len() as u32).to_le_bytes());
            v.extend((name.len() as u16).to_le_bytes());
            v.extend(0u16.to_le_bytes());
            if central {
                v.extend([0, 0, 0, 0, 0, 0]);
                v.extend((mode << 16).to_le_bytes());
                v.extend(at.to_le_bytes());
            }
            v.extend(name.as_bytes());
        };
        head(&mut out, false);
        out.extend(&packed);
        head(&mut dir, true);
    }
    eocd(out, &dir, entries.len() as u16)
}

/// `out` with the central directory `dir` of `count` entries and its end record appended.
pub fn eocd(mut out: Vec<u8>, dir: &[u8], count: u16) -> Vec<u8> {
    let dir_at = out.len() as u32;
    out.extend(dir);
    out.extend([0x50, 0x4b, 0x05, 0x06, 0, 0, 0, 0]);
    out.extend(count.to_le_bytes());
    out.extend(count.to_le_bytes());
    out.extend((dir.len() as u32).to_le_bytes());
    out.extend(dir_at.to_le_bytes());
    out.extend(0u16.to_le_bytes());
    out
}

/// A tmpfs of `size` mounted at `at` (`.0`), unmounted when dropped; `None` where mounting
/// is not allowed (not root).
pub struct Tmpfs(pub std::path::PathBuf);

impl Tmpfs {
    pub fn mount(at: &Path, size: &str) -> Option<Self> {
        std::fs::create_dir_all(at).ok()?;
        let ok = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(at)
            .stderr(Stdio::null())
            .status()
            .ok()?
            .success();
        ok.then(|| Self(at.to_owned()))
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

/// Writes `path` until its filesystem is full, the last partial blocks too.
pub fn fill(path: &Path) {
    use std::io::Write;
    let mut f = std::fs::File::create(path).unwrap();
    let block = vec![0xA5u8; 64 * 1024];
    while f.write_all(&block).and_then(|()| f.flush()).is_ok() {}
    let small = [0u8; 512];
    while f.write_all(&small).is_ok() {}
    let _ = f.sync_all();
}
