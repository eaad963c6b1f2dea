//! The store's contract, on both backends (shared/spec/cluster.md): every test runs the
//! same steps on SQLite (a temporary folder) and on PostgreSQL (a fresh database on the
//! test server, `common::pg_server_url`): records, exclusive claims, leases and their
//! tokens, the reaper.

mod common;

use glimpse::service::error_code::ErrorCode;
use glimpse::service::store::{
    Beat, Database, JobError, JobState, Progress, Store, MAX_ATTEMPTS, MAX_LEASE_ATTEMPTS,
};
use std::time::Duration;
use uuid::Uuid;

/// The two stores, each with the folder that holds it (or its files).
async fn stores() -> Vec<(Store, tempfile::TempDir)> {
    let a = tempfile::tempdir().unwrap();
    let sqlite = Store::open(a.path()).await.unwrap();
    let b = tempfile::tempdir().unwrap();
    let pg = Store::connect(
        &Database::Postgres(common::fresh_pg_database().await),
        b.path(),
    )
    .await
    .unwrap();
    vec![(sqlite, a), (pg, b)]
}

async fn insert(store: &Store, name: &str) -> Uuid {
    let id = Uuid::now_v7();
    store.insert(id, name, "{}", &[]).await.unwrap();
    id
}

fn progress(iteration: u32) -> Progress {
    Progress {
        iteration,
        pixels_traced: 1234,
        pixel_fraction: 0.25,
        elapsed_ms: 99,
        mean_distance: Some(0.5),
        eta_ms: None,
        eta_low_ms: None,
        eta_high_ms: None,
        eta_confidence: None,
        finishing: false,
        denoised: false,
    }
}

const LEASE: Duration = Duration::from_secs(30);

#[tokio::test]
async fn records_are_typed_and_listed_newest_first() {
    for (store, _dir) in stores().await {
        let b = store.backend();
        let ids = [
            insert(&store, "a").await,
            insert(&store, "b").await,
            insert(&store, "c").await,
        ];
        let list = store.list(None, 2).await.unwrap();
        let names: Vec<_> = list.iter().map(|j| j.name.as_str()).collect();
        assert_eq!(names, ["c", "b"], "{b}");
        let claim = store.claim(Some("w1"), LEASE).await.unwrap().unwrap();
        assert_eq!(claim.id, ids[0], "{b}: the oldest job is claimed first");
        let error = JobError::new(ErrorCode::Timeout, "too long");
        let done = store
            .finish_leased(
                claim.id,
                claim.token,
                JobState::Failed,
                Some(&progress(3)),
                None,
                Some(&error),
                true,
            )
            .await
            .unwrap();
        assert!(done.is_some(), "{b}");
        let j = store.get(claim.id).await.unwrap().unwrap();
        assert_eq!(j.state, JobState::Failed, "{b}");
        assert_eq!(j.progress, Some(progress(3)), "{b}");
        assert_eq!(j.error, Some(error), "{b}");
        assert_eq!((j.attempt, j.worker.as_deref()), (1, Some("w1")), "{b}");
        assert!(j.has_frame && j.finished_at.is_some(), "{b}");
        let counts = store.count_by_state().await.unwrap();
        assert!(counts.contains(&(JobState::Queued, 2)), "{b}: {counts:?}");
        assert!(counts.contains(&(JobState::Failed, 1)), "{b}: {counts:?}");
        let failed = store.list(Some(JobState::Failed), 10).await.unwrap();
        assert_eq!(failed.len(), 1, "{b}");
        assert!(store.delete_finished(claim.id).await.unwrap(), "{b}");
        assert!(store.get(claim.id).await.unwrap().is_none(), "{b}");
        assert_eq!(store.queued_count().await.unwrap(), 2, "{b}");
        store.ping().await.unwrap();
    }
}

#[tokio::test]
async fn concurrent_claims_take_each_job_once() {
    for (store, _dir) in stores().await {
        let b = store.backend();
        let mut ids = Vec::new();
        for k in 0..5 {
            ids.push(insert(&store, &format!("j{k}")).await);
        }
        // 12 claimers race for 5 jobs: each job goes to exactly one of them.
        let claims = futures_util::future::join_all((0..12).map(|k| {
            let store = store.clone();
            async move { store.claim(Some(&format!("w{k}")), LEASE).await.unwrap() }
        }))
        .await;
        let mut got: Vec<Uuid> = claims.iter().flatten().map(|c| c.id).collect();
        got.sort();
        assert_eq!(got, ids, "{b}");
        assert!(
            store.claim(Some("late"), LEASE).await.unwrap().is_none(),
            "{b}"
        );
    }
}

/// A claimer reads its clock before its connection is free, so the job it gets may have been
/// created after that reading (another node's insert, or a slow pool): the job still never
/// starts before it was created.
#[tokio::test]
async fn a_job_never_starts_before_it_was_created() {
    use sqlx::Connection;
    const FUTURE: &str = "2999-01-01T00:00:00.000Z";
    const SET: &str = "UPDATE jobs SET created_at = $1 WHERE id = $2";
    async fn claim_starts_at_creation(store: &Store, id: Uuid) {
        let claim = store.claim(Some("w"), LEASE).await.unwrap().unwrap();
        assert_eq!(claim.started_at, FUTURE, "{}", store.backend());
        let record = store.get(id).await.unwrap().unwrap();
        assert_eq!(record.started_at.as_deref(), Some(FUTURE));
    }

    let dir = tempfile::tempdir().unwrap();
    let sqlite = Store::open(dir.path()).await.unwrap();
    let id = insert(&sqlite, "late-created").await;
    let file = format!("sqlite://{}", dir.path().join("glimpse.db").display());
    let mut db = sqlx::SqliteConnection::connect(&file).await.unwrap();
    let set = sqlx::query(SET).bind(FUTURE).bind(id.to_string());
    set.execute(&mut db).await.unwrap();
    claim_starts_at_creation(&sqlite, id).await;

    let url = common::fresh_pg_database().await;
    let dir = tempfile::tempdir().unwrap();
    let pg = Store::connect(&Database::Postgres(url.clone()), dir.path())
        .await
        .unwrap();
    let id = insert(&pg, "late-created").await;
    let mut db = sqlx::PgConnection::connect(&url).await.unwrap();
    let set = sqlx::query(SET).bind(FUTURE).bind(id.to_string());
    set.execute(&mut db).await.unwrap();
    claim_starts_at_creation(&pg, id).await;
}

#[tokio::test]
async fn a_write_with_a_stale_attempt_token_is_refused() {
    for (store, _dir) in stores().await {
        let b = store.backend();
        let id = insert(&store, "contested").await;
        let first = store
            .claim(Some("worker-a"), Duration::from_millis(50))
            .await
            .unwrap()
            .unwrap();
        assert_eq!(
            store
                .heartbeat(id, first.token, Duration::from_millis(50), None)
                .await
                .unwrap(),
            Beat::Held {
                cancel_requested: false
            },
            "{b}"
        );
        // worker-a stops beating (killed, or cut off): its lease expires, the reaper puts
        // the job back and worker-b takes it as attempt 2.
        tokio::time::sleep(Duration::from_millis(120)).await;
        let reaped = store.reap(MAX_LEASE_ATTEMPTS).await.unwrap();
        assert_eq!(reaped.requeued, 1, "{b}");
        let second = store.claim(Some("worker-b"), LEASE).await.unwrap().unwrap();
        assert_eq!((second.id, second.attempt), (id, 2), "{b}");
        // worker-a comes back: every write it tries is refused and changes nothing.
        let late = store
            .heartbeat(id, first.token, LEASE, Some(&progress(9)))
            .await
            .unwrap();
        assert_eq!(late, Beat::Lost, "{b}");
        let finished = store
            .finish_leased(
                id,
                first.token,
                JobState::Succeeded,
                Some(&progress(9)),
                None,
                None,
                true,
            )
            .await
            .unwrap();
        assert!(finished.is_none(), "{b}: a stale token finished the job");
        assert!(!store.release(id, first.token).await.unwrap(), "{b}");
        let j = store.get(id).await.unwrap().unwrap();
        assert_eq!(j.state, JobState::Running, "{b}");
        assert_eq!(
            (j.attempt, j.worker.as_deref()),
            (2, Some("worker-b")),
            "{b}"
        );
        assert_eq!(j.progress, None, "{b}: the stale progress was written");
        // The holder's writes go through.
        let beat = store
            .heartbeat(id, second.token, LEASE, Some(&progress(1)))
            .await
            .unwrap();
        assert_eq!(
            beat,
            Beat::Held {
                cancel_requested: false
            },
            "{b}"
        );
        assert_eq!(
            store.get(id).await.unwrap().unwrap().progress,
            Some(progress(1))
        );
        assert!(store.request_cancel(id).await.unwrap(), "{b}");
        let beat = store
            .heartbeat(id, second.token, LEASE, None)
            .await
            .unwrap();
        assert_eq!(
            beat,
            Beat::Held {
                cancel_requested: true
            },
            "{b}: the cancel reaches the worker"
        );
        let done = store
            .finish_leased(
                id,
                second.token,
                JobState::Cancelled,
                None,
                None,
                None,
                false,
            )
            .await
            .unwrap();
        assert!(done.is_some(), "{b}");
    }
}

#[tokio::test]
async fn the_reaper_is_idempotent_and_stops_after_three_attempts() {
    for (store, _dir) in stores().await {
        let b = store.backend();
        let id = insert(&store, "poison").await;
        let short = Duration::from_millis(30);
        for attempt in 1..=MAX_LEASE_ATTEMPTS {
            let c = store.claim(Some("doomed"), short).await.unwrap().unwrap();
            assert_eq!((c.id, c.attempt), (id, attempt), "{b}");
            tokio::time::sleep(Duration::from_millis(80)).await;
            let r = store.reap(MAX_LEASE_ATTEMPTS).await.unwrap();
            let again = store.reap(MAX_LEASE_ATTEMPTS).await.unwrap();
            assert_eq!(
                again,
                Default::default(),
                "{b}: a second pass changed something"
            );
            if attempt < MAX_LEASE_ATTEMPTS {
                assert_eq!((r.requeued, r.failed), (1, 0), "{b}");
            } else {
                assert_eq!((r.requeued, r.failed), (0, 1), "{b}");
            }
        }
        let j = store.get(id).await.unwrap().unwrap();
        assert_eq!(j.state, JobState::Failed, "{b}");
        let e = j.error.unwrap();
        assert_eq!(e.code, ErrorCode::Poison, "{b}");
        assert!(e.message.contains("3 attempts"), "{b}: {}", e.message);
        assert!(
            store.claim(Some("late"), short).await.unwrap().is_none(),
            "{b}"
        );
        // A live lease is never reaped; an expired one with a cancel asked ends cancelled.
        let live = insert(&store, "live").await;
        let c = store.claim(Some("alive"), LEASE).await.unwrap().unwrap();
        assert_eq!(
            store.reap(MAX_LEASE_ATTEMPTS).await.unwrap(),
            Default::default(),
            "{b}"
        );
        assert_eq!(
            store.get(live).await.unwrap().unwrap().state,
            JobState::Running
        );
        let gone = insert(&store, "cancelled while its worker died").await;
        let c2 = store.claim(Some("dies"), short).await.unwrap().unwrap();
        assert_eq!(c2.id, gone, "{b}");
        assert!(store.request_cancel(gone).await.unwrap());
        tokio::time::sleep(Duration::from_millis(80)).await;
        let r = store.reap(MAX_LEASE_ATTEMPTS).await.unwrap();
        assert_eq!(r.cancelled, 1, "{b}");
        assert_eq!(
            store.get(gone).await.unwrap().unwrap().state,
            JobState::Cancelled
        );
        drop(c);
    }
}

#[tokio::test]
async fn single_node_recovery_is_the_same_on_both_backends() {
    for (store, _dir) in stores().await {
        let b = store.backend();
        let id = insert(&store, "crashes the server").await;
        for start in 1..=MAX_ATTEMPTS {
            assert_eq!(store.recover().await.unwrap(), [id], "{b}");
            assert!(store
                .mark_running_at(id, "2026-01-01T00:00:00.000Z")
                .await
                .unwrap());
            let j = store.get(id).await.unwrap().unwrap();
            assert_eq!(j.attempt, start, "{b}");
        }
        // Found running at the start-up after its second start: a poison job.
        assert!(store.recover().await.unwrap().is_empty(), "{b}");
        let j = store.get(id).await.unwrap().unwrap();
        assert_eq!(j.state, JobState::Failed, "{b}");
        assert_eq!(j.error.unwrap().code, ErrorCode::Poison, "{b}");
    }
}

#[tokio::test]
async fn a_postgres_database_of_another_program_is_refused() {
    use sqlx::Connection;
    let url = common::fresh_pg_database().await;
    let mut c = sqlx::PgConnection::connect(&url).await.unwrap();
    sqlx::query("CREATE TABLE invoices (n INT)")
        .execute(&mut c)
        .await
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let err = Store::connect(&Database::Postgres(url), dir.path())
        .await
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("not a Glimpse job store") && err.contains("invoices"),
        "{err}"
    );
}

#[tokio::test]
async fn healthz_says_whether_the_node_reaches_its_database() {
    use sqlx::Connection;
    let url = common::fresh_pg_database().await;
    let name = url.rsplit('/').next().unwrap().to_owned();
    let dir = tempfile::tempdir().unwrap();
    let mut config = glimpse::service::Config::new(dir.path());
    config.database = Some(Database::Postgres(url));
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let health = format!("http://{}/healthz", listener.local_addr().unwrap());
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(glimpse::service::run(listener, config, async {
        let _ = stopped.await;
    }));
    let c = reqwest::Client::new();
    let get = || async {
        let r = c.get(&health).send().await.unwrap();
        (
            r.status().as_u16(),
            r.json::<serde_json::Value>().await.unwrap(),
        )
    };
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while c.get(&health).send().await.is_err() {
        assert!(
            std::time::Instant::now() < deadline,
            "the node did not come up"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let (status, body) = get().await;
    assert_eq!(
        (status, &body["database"]),
        (200, &serde_json::json!("postgres"))
    );
    // The database goes away under the node (its connections cut): 503, saying so.
    let mut admin = sqlx::PgConnection::connect(&common::pg_server_url())
        .await
        .unwrap();
    sqlx::query(&format!("DROP DATABASE {name} WITH (FORCE)"))
        .execute(&mut admin)
        .await
        .unwrap();
    let (status, body) = get().await;
    assert_eq!(status, 503, "{body}");
    assert_eq!(body["status"], "database_unreachable", "{body}");
    assert!(body["error"]["message"]
        .as_str()
        .unwrap()
        .contains("cannot reach"));
    // Back: healthy again without a restart.
    sqlx::query(&format!("CREATE DATABASE {name}"))
        .execute(&mut admin)
        .await
        .unwrap();
    let (status, body) = get().await;
    assert_eq!(status, 200, "{body}");
    let _ = stop.send(());
    let _ = tokio::time::timeout(Duration::from_secs(15), server).await;
}

/// Renders nothing until it is cancelled (a render long enough to lose its lease in).
fn until_cancelled(
    _scene: glimpse::scene::Scene,
    _opts: &glimpse::progressive::RenderOptions,
    _on_frame: &mut dyn FnMut(&glimpse::progressive::Frame),
    cancel: &glimpse::cancel::CancelToken,
) -> Result<glimpse::progressive::Frame, glimpse::progressive::RenderError> {
    while !cancel.is_cancelled() {
        std::thread::sleep(Duration::from_millis(5));
    }
    Err(glimpse::progressive::RenderError::Cancelled)
}

const SPHERE: &str = r#"{"version": 1, "image": {"width": 8, "height": 6},
    "camera": {"position": [0, 0, -3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_y": 40},
    "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
    "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "w"}]}"#;

/// The service's side of a lost lease: a worker presumed dead (its job taken back while
/// it still renders) learns it from its next heartbeat, stops and writes nothing; the
/// job's next attempt is a new claim.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_that_lost_its_lease_stops_and_writes_nothing() {
    use glimpse::service::jobs::{Jobs, Node, DEFAULT_JOB_TIMEOUT};
    use glimpse::service::metrics::Metrics;
    use sqlx::Connection;
    use std::sync::atomic::Ordering;
    let url = common::fresh_pg_database().await;
    let dir = tempfile::tempdir().unwrap();
    let store = Store::connect(&Database::Postgres(url.clone()), dir.path())
        .await
        .unwrap();
    let metrics = std::sync::Arc::new(Metrics::default());
    let node = Node {
        name: Some("n1".to_owned()),
        workers: 1,
        lease: Duration::from_secs(1),
        job_memory: glimpse::service::jobs::DEFAULT_JOB_MEMORY,
    };
    let jobs = Jobs::start_with(
        store.clone(),
        node,
        glimpse::service::server_limits(),
        8,
        DEFAULT_JOB_TIMEOUT,
        std::sync::Arc::clone(&metrics),
        until_cancelled,
    )
    .await
    .unwrap();
    let id = jobs.submit("victim", SPHERE).await.unwrap().id;
    let until = |what: &'static str| {
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        move || assert!(std::time::Instant::now() < deadline, "{what}")
    };
    let check = until("never claimed");
    while store.get(id).await.unwrap().unwrap().state != JobState::Running {
        check();
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    // Taken back in one statement, as the reaper does once a lease has expired.
    let mut db = sqlx::PgConnection::connect(&url).await.unwrap();
    sqlx::query("UPDATE jobs SET state = 'queued', started_at = NULL, lease_token = NULL, lease_expires_at = NULL WHERE id = $1")
        .bind(id.to_string())
        .execute(&mut db)
        .await
        .unwrap();
    // The next heartbeat (every 100 ms) finds the lease gone; the worker, free again,
    // claims the job anew.
    let check = until("the lost lease was never noticed, or the job never claimed again");
    loop {
        let j = store.get(id).await.unwrap().unwrap();
        if j.attempt == 2 && j.state == JobState::Running {
            break;
        }
        check();
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    assert_eq!(metrics.lease_losses.load(Ordering::Relaxed), 1);
    assert_eq!(metrics.claims.load(Ordering::Relaxed), 2);
    // The first attempt wrote no end: the job is not finished and has no image, and the
    // first attempt's folder is gone (only the running attempt's is left).
    let j = store.get(id).await.unwrap().unwrap();
    assert!(j.finished_at.is_none() && !j.has_frame, "{j:?}");
    let image = store.layer_path(&j, glimpse::service::store::Layer::Image, false);
    assert!(std::fs::read(&image).unwrap_or_default().is_empty());
    // The new attempt makes its folder just after its claim, off the claim's path.
    let check = until("the running attempt never made its folder");
    while !store.files_dir(&j).is_dir() {
        check();
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    assert_eq!(attempt_folders(&store, id), [store.files_dir(&j)]);
    jobs.shutdown().await;
}

/// The attempts' folders in a job's folder.
fn attempt_folders(store: &Store, id: Uuid) -> Vec<std::path::PathBuf> {
    let mut found: Vec<_> = std::fs::read_dir(store.job_dir(id))
        .map(|rd| {
            rd.flatten()
                .map(|e| e.path())
                .filter(|p| p.is_dir())
                .collect()
        })
        .unwrap_or_default();
    found.sort();
    found
}

/// The final image's write is fenced by the attempt token, not only by a renewal of the
/// lease: a worker that stalls for longer than its whole lease right before writing
/// its final image (forged here: a claim whose lease runs out, whose job a real worker
/// then takes over and finishes) writes into its own attempt's folder, its end is
/// refused, and the job's image stays the new owner's, as served; the owner removed the
/// stale attempt's earlier folder, and the stale one removes what it wrote late.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stale_attempt_writing_its_final_image_late_never_replaces_the_owners() {
    use glimpse::service::jobs::{FrameBytes, FrameLookup, Jobs, Node, DEFAULT_JOB_TIMEOUT};
    use glimpse::service::store::{prepare_job_dir_blocking, write_final_image_blocking, Layer};
    let dir = tempfile::tempdir().unwrap();
    let store = Store::connect(
        &Database::Postgres(common::fresh_pg_database().await),
        dir.path(),
    )
    .await
    .unwrap();
    let id = Uuid::now_v7();
    store.insert(id, "contested", SPHERE, &[]).await.unwrap();
    // The stale worker: claimed, its folder prepared (as while it renders), then silent
    // past its lease.
    let stale = store
        .claim(Some("stale"), Duration::from_millis(50))
        .await
        .unwrap()
        .unwrap();
    let stale_dir = store.attempt_dir(id, stale.token);
    prepare_job_dir_blocking(&stale_dir).unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    // A node whose reaper takes the job back and whose worker renders it to the end.
    let node = Node {
        name: Some("owner".to_owned()),
        workers: 1,
        lease: Duration::from_secs(1),
        job_memory: glimpse::service::jobs::DEFAULT_JOB_MEMORY,
    };
    let jobs = Jobs::start_with(
        store.clone(),
        node,
        glimpse::service::server_limits(),
        8,
        DEFAULT_JOB_TIMEOUT,
        std::sync::Arc::new(glimpse::service::metrics::Metrics::default()),
        glimpse::service::jobs::render_scene,
    )
    .await
    .unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(15);
    let owned = loop {
        let j = store.get(id).await.unwrap().unwrap();
        if j.state == JobState::Succeeded {
            break j;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "never finished: {j:?}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    assert_eq!((owned.attempt, owned.worker.as_deref()), (2, Some("owner")));
    let owner_dir = store.files_dir(&owned);
    assert_ne!(owner_dir, stale_dir);
    // The image as served from its stored file (while the owner still writes its
    // other layers, the job is served from its memory).
    let served = || async {
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        loop {
            match jobs.frame(id, Layer::Image, false).await.unwrap() {
                FrameLookup::Found(FrameBytes::File(path)) => break std::fs::read(path).unwrap(),
                FrameLookup::Found(FrameBytes::Memory(_)) => {}
                _ => panic!("the final image is not served"),
            }
            assert!(
                std::time::Instant::now() < deadline,
                "never served from its file"
            );
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    };
    let owners_png = served().await;
    assert!(owners_png.starts_with(b"\x89PNG"));
    assert_eq!(
        attempt_folders(&store, id),
        std::slice::from_ref(&owner_dir)
    );

    // The stale worker wakes up right before its write: files cannot check its token,
    // so the write lands, in its own folder; then its end is refused by the token.
    write_final_image_blocking(&stale_dir, b"the stale attempt's image").unwrap();
    let end = store
        .finish_leased(
            id,
            stale.token,
            JobState::Succeeded,
            Some(&progress(9)),
            None,
            None,
            true,
        )
        .await
        .unwrap();
    assert!(end.is_none(), "a stale attempt's end was recorded");
    assert_eq!(served().await, owners_png, "the owner's image was replaced");
    let j = store.get(id).await.unwrap().unwrap();
    assert_eq!(j.attempt_token, owned.attempt_token);
    store.discard_attempt_blocking(id, stale.token);
    assert_eq!(attempt_folders(&store, id), [owner_dir]);
    jobs.shutdown().await;
}
