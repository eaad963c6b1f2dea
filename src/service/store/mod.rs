//! Durable job records behind one interface, on two backends through sqlx: SQLite (the
//! embedded default, WAL mode, `migrations/`) and PostgreSQL (many nodes on one
//! database, shared/spec/cluster.md; `migrations/postgres/`). Both run the same SQL:
//! every column is text or a 64-bit integer and parameters are `$1, $2, …`, which SQLite
//! reads as well as PostgreSQL; where the two dialects differ the statement says so.
//!
//! - [`record`]: the typed records ([`JobRecord`], [`Progress`], [`JobError`], [`Layer`]);
//! - [`sqlite`], [`postgres`]: opening each backend (its settings, its migrations);
//! - [`files`]: the image files of finished jobs beside the database (`<data>/jobs/<id>/`);
//! - [`fault`]: storage faults injected at any of these writes, for tests; [`health`]:
//!   which kinds of writes are failing now;
//! - [`notify`]: `LISTEN`/`NOTIFY` news between nodes on PostgreSQL (a job queued, a
//!   frame relayed), which hastens what the nodes also poll for.
//!
//! service-api.md "Durability": a job is inserted (and the transaction committed, with
//! `synchronous = FULL` on SQLite) before the `201` leaves; at start-up [`Store::recover`]
//! puts jobs found `running` back to `queued`. At a job's end, `image.png` is written and
//! synced, then the record is committed, then `done` goes out; the other layers and the
//! EXR are written after (`jobs.rs`), so a crash in between leaves a finished job with its
//! state, statistics and image, whose other layers answer 404.

pub mod fault;
mod files;
pub mod health;
mod notify;
mod postgres;
mod record;
mod sqlite;

pub use files::{
    clear_iterations_blocking, file_present, iteration_path, kept_iterations_blocking,
    prepare_job_dir_blocking, remove_iteration_blocking, write_files_blocking,
    write_final_image_blocking, write_iteration_blocking, FINAL_IMAGE_FILE, ITERATIONS_DIR,
};
pub use notify::{Listener, News};
pub use record::{JobError, JobRecord, JobState, Layer, Progress};

use record::{column_text, Row, COLUMNS};
use std::path::{Path, PathBuf};
use uuid::Uuid;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database: {0}")]
    Db(#[from] sqlx::Error),
    #[error("migration: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    #[error("file: {0}")]
    Io(#[from] std::io::Error),
    #[error("corrupt record: {0}")]
    Corrupt(String),
    /// A finished job's record says it has a frame, but its image file is gone.
    #[error("the files of job {0} are missing: {path} is gone (removed outside the server?)", path = .1.display())]
    FilesMissing(Uuid, PathBuf),
}

/// What kind of failure a [`StoreError`] is, for the answer a client gets: a database
/// this node cannot reach (PostgreSQL down or cut off) is not a disk that refuses a write,
/// and telling a client "is the disk full?" for the first sends its operator to the wrong
/// machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Failure {
    /// No connection to the database: refused, reset, timed out, the server shutting
    /// down, the database gone or the login refused (SQLSTATE classes 08 and 28, 57P01–
    /// 57P03, 3D000).
    Unreachable,
    /// A finished job's files are gone, for good (410).
    FilesMissing,
    /// The disk refused a write: full (`ENOSPC`, `SQLITE_FULL`) or read-only.
    Full,
    /// Anything else the database or the file system said.
    Other,
    /// A record that cannot be read (a bug or a damaged database, not a passing fault).
    Corrupt,
}

impl StoreError {
    #[must_use]
    pub fn failure(&self) -> Failure {
        match self {
            Self::Db(e) => db_failure(e),
            Self::Migrate(sqlx::migrate::MigrateError::Execute(e)) => db_failure(e),
            Self::Migrate(_) => Failure::Other,
            Self::Io(e) => io_failure(e),
            Self::Corrupt(_) => Failure::Corrupt,
            Self::FilesMissing(..) => Failure::FilesMissing,
        }
    }
}

fn io_failure(e: &std::io::Error) -> Failure {
    use std::io::ErrorKind as K;
    match e.kind() {
        K::StorageFull | K::ReadOnlyFilesystem | K::QuotaExceeded => Failure::Full,
        K::ConnectionRefused
        | K::ConnectionReset
        | K::ConnectionAborted
        | K::NotConnected
        | K::BrokenPipe
        | K::TimedOut
        | K::UnexpectedEof
        | K::HostUnreachable
        | K::NetworkUnreachable
        | K::AddrNotAvailable => Failure::Unreachable,
        _ => Failure::Other,
    }
}

fn db_failure(e: &sqlx::Error) -> Failure {
    match e {
        sqlx::Error::PoolTimedOut
        | sqlx::Error::PoolClosed
        | sqlx::Error::WorkerCrashed
        | sqlx::Error::Tls(_)
        | sqlx::Error::Protocol(_) => Failure::Unreachable,
        sqlx::Error::Io(io) => match io_failure(io) {
            // A socket's other errors are the connection's too.
            Failure::Other => Failure::Unreachable,
            f => f,
        },
        sqlx::Error::Database(d) => {
            let code = d.code().unwrap_or_default();
            match &*code {
                // SQLite: SQLITE_FULL, SQLITE_READONLY (and their extended codes' low byte).
                "13" | "8" => Failure::Full,
                c if c
                    .parse::<i32>()
                    .is_ok_and(|n| n & 0xff == 13 || n & 0xff == 8) =>
                {
                    Failure::Full
                }
                // PostgreSQL: disk_full, out of space for a table.
                "53100" => Failure::Full,
                // Connection exceptions, the server shutting down or starting, and a
                // connection refused at its start (the database is gone, the login
                // refused): no statement got through.
                c if c.starts_with("08")
                    || c.starts_with("28")
                    || matches!(c, "57P01" | "57P02" | "57P03" | "3D000") =>
                {
                    Failure::Unreachable
                }
                _ => Failure::Other,
            }
        }
        _ => Failure::Other,
    }
}

/// At most 64 characters of `s` (with "…" when cut), for messages that quote stored or
/// client-sent text.
#[must_use]
pub fn clip(s: &str) -> String {
    clip_to(s, 64)
}

/// At most `chars` characters of `s`, with "…" when cut.
#[must_use]
pub fn clip_to(s: &str, chars: usize) -> String {
    match s.char_indices().nth(chars) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_owned(),
    }
}

/// The current time as RFC 3339 UTC (`2026-11-22T10:00:00.123Z`).
#[must_use]
pub fn now_rfc3339() -> String {
    rfc3339_millis(time::OffsetDateTime::now_utc())
}

/// RFC 3339 UTC with exactly three fractional digits. `time`'s `Rfc3339` trims trailing
/// zeros (`.8Z` vs `.82Z`), which breaks the string order clients (and tests) rely on:
/// `"…06.8Z" > "…06.82Z"` although 0.80 < 0.82. A fixed width keeps string order = time order.
fn rfc3339_millis(t: time::OffsetDateTime) -> String {
    const FMT: &[time::format_description::BorrowedFormatItem<'static>] = time::macros::format_description!(
        "[year]-[month]-[day]T[hour]:[minute]:[second].[subsecond digits:3]Z"
    );
    t.to_offset(time::UtcOffset::UTC)
        .format(FMT)
        .unwrap_or_default()
}

use crate::service::error_code::ErrorCode;

/// Starts of a job after which a crash during its render makes it a poison job (failed at
/// the next start-up instead of run again): two, so that one unrelated crash (a power cut,
/// an operator's kill) does not fail a good job.
pub const MAX_ATTEMPTS: u32 = 2;

/// Where the jobs live: `--database sqlite://DIR` (or `--data DIR`) or
/// `--database postgres://USER@HOST/DB`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Database {
    Sqlite(PathBuf),
    Postgres(String),
}

impl Database {
    /// Reads a `--database` URL; the error names what was expected.
    pub fn parse(url: &str) -> Result<Self, String> {
        if let Some(dir) = url.strip_prefix("sqlite://") {
            if dir.is_empty() {
                return Err("--database sqlite:// needs a folder: sqlite://DIR".to_owned());
            }
            return Ok(Self::Sqlite(PathBuf::from(dir)));
        }
        if url.starts_with("postgres://") || url.starts_with("postgresql://") {
            return Ok(Self::Postgres(url.to_owned()));
        }
        Err(format!(
            "--database {:?} is neither sqlite://DIR nor postgres://USER@HOST/DB",
            clip(url)
        ))
    }

    /// The URL without a password, for logs and error messages.
    #[must_use]
    pub fn display(&self) -> String {
        match self {
            Self::Sqlite(dir) => format!("sqlite://{}", dir.display()),
            Self::Postgres(url) => postgres::without_password(url),
        }
    }
}

/// Whether `conn` is counted inside a transaction (for the pools' release check).
fn in_transaction<C: sqlx::Connection>(conn: &C) -> bool {
    conn.is_in_transaction()
}

#[derive(Clone, Debug)]
enum Pool {
    Sqlite(sqlx::SqlitePool),
    Postgres(sqlx::PgPool),
}

/// Runs `$body` with `$p` bound to whichever pool the store has: the statement is the
/// same text on both backends, compiled once per driver.
macro_rules! on_pool {
    ($store:expr, $p:ident => $body:expr) => {
        match &$store.pool {
            Pool::Sqlite($p) => $body,
            Pool::Postgres($p) => $body,
        }
    };
}

mod lease;
pub use lease::{Beat, Claim, LeaseToken, Reaped, MAX_LEASE_ATTEMPTS};

/// The name of an attempt's folder inside its job's, before the token ([`Store::attempt_dir`]).
const ATTEMPT_PREFIX: &str = "attempt-";

/// The job store (cheap to clone: a pool handle and a folder).
#[derive(Clone, Debug)]
pub struct Store {
    pool: Pool,
    jobs_dir: PathBuf,
}

impl Store {
    /// Opens (creating if missing) `data_dir/glimpse.db` and runs the migrations.
    pub async fn open(data_dir: &Path) -> Result<Self, StoreError> {
        Self::connect(&Database::Sqlite(data_dir.to_owned()), data_dir).await
    }

    /// Opens `database` (running its migrations); finished jobs' images go under
    /// `files_dir/jobs/`.
    pub async fn connect(database: &Database, files_dir: &Path) -> Result<Self, StoreError> {
        std::fs::create_dir_all(files_dir)?;
        let jobs_dir = files_dir.join("jobs");
        std::fs::create_dir_all(&jobs_dir)?;
        let pool = match database {
            Database::Sqlite(dir) => Pool::Sqlite(sqlite::open(dir).await?),
            Database::Postgres(url) => Pool::Postgres(postgres::open(url).await?),
        };
        Ok(Self { pool, jobs_dir })
    }

    /// Which backend this is (`sqlite` or `postgres`), for `/healthz` and the logs.
    #[must_use]
    pub fn backend(&self) -> &'static str {
        match self.pool {
            Pool::Sqlite(_) => "sqlite",
            Pool::Postgres(_) => "postgres",
        }
    }

    /// True on PostgreSQL: other nodes may share this database (cluster.md), so what a
    /// worker renders must reach them through it, and a lease may be lost to another node.
    #[must_use]
    pub fn is_shared(&self) -> bool {
        matches!(self.pool, Pool::Postgres(_))
    }

    /// One round trip to the database: does this node reach it?
    pub async fn ping(&self) -> Result<(), StoreError> {
        on_pool!(self, p => sqlx::query("SELECT 1").execute(p).await.map(|r| r.rows_affected()))?;
        Ok(())
    }

    /// Marks a queued or running job's cancel request durably (before its `202`); false
    /// if the job is not queued or running any more.
    pub async fn request_cancel(&self, id: Uuid) -> Result<bool, StoreError> {
        fault::check(fault::Write::RequestCancel)?;
        let q =
            "UPDATE jobs SET cancel_requested = 1 WHERE id = $1 AND state IN ('queued', 'running')";
        let r = on_pool!(self, p => sqlx::query(q).bind(id.to_string()).execute(p).await.map(|r| r.rows_affected()))?;
        Ok(r == 1)
    }

    pub async fn close(&self) {
        on_pool!(self, p => p.close().await);
    }

    /// Folder of a job's images. `id` is a parsed UUID, so the path cannot escape.
    #[must_use]
    pub fn job_dir(&self, id: Uuid) -> PathBuf {
        self.jobs_dir.join(id.hyphenated().to_string())
    }

    /// Stores a new queued job with what its submission was warned of (kept bounded:
    /// [`record::bounded_warnings`]).
    pub async fn insert(
        &self,
        id: Uuid,
        name: &str,
        scene: &str,
        warnings: &[String],
    ) -> Result<JobRecord, StoreError> {
        fault::check(fault::Write::Insert)?;
        let created = now_rfc3339();
        let warnings = record::bounded_warnings(warnings);
        let q = "INSERT INTO jobs (id, name, state, scene, created_at, warnings) VALUES ($1, $2, 'queued', $3, $4, $5)";
        on_pool!(self, p => sqlx::query(q)
            .bind(id.to_string())
            .bind(name)
            .bind(scene)
            .bind(&created)
            .bind(column_text(Some(&warnings).filter(|w| !w.is_empty())))
            .execute(p)
            .await
            .map(|r| r.rows_affected()))?;
        Ok(JobRecord {
            id,
            state: JobState::Queued,
            name: name.to_owned(),
            created_at: created,
            started_at: None,
            finished_at: None,
            progress: None,
            stats: None,
            error: None,
            attempt: 0,
            worker: None,
            warnings,
            has_frame: false,
            attempt_token: None,
        })
    }

    pub async fn get(&self, id: Uuid) -> Result<Option<JobRecord>, StoreError> {
        let q = format!("SELECT {COLUMNS} FROM jobs WHERE id = $1");
        let row: Option<Row> = on_pool!(self, p => sqlx::query_as(&q)
            .bind(id.to_string())
            .fetch_optional(p)
            .await)?;
        row.map(Row::into_record).transpose()
    }

    /// Every finished job's id and finishing time (RFC 3339), newest first: what
    /// retention (`service::retention`) weighs.
    pub async fn finished(&self) -> Result<Vec<(String, Option<String>)>, StoreError> {
        let q = "SELECT id, finished_at FROM jobs \
                 WHERE state IN ('succeeded', 'failed', 'cancelled') ORDER BY id DESC";
        Ok(on_pool!(self, p => sqlx::query_as(q).fetch_all(p).await)?)
    }

    pub async fn scene(&self, id: Uuid) -> Result<Option<String>, StoreError> {
        let q = "SELECT scene FROM jobs WHERE id = $1";
        Ok(on_pool!(self, p => sqlx::query_scalar(q)
            .bind(id.to_string())
            .fetch_optional(p)
            .await)?)
    }

    /// Newest first (UUIDv7 ids sort by creation time).
    pub async fn list(
        &self,
        state: Option<JobState>,
        limit: u32,
    ) -> Result<Vec<JobRecord>, StoreError> {
        let limit = i64::from(limit);
        let rows: Vec<Row> = match state {
            Some(s) => {
                let q = format!(
                    "SELECT {COLUMNS} FROM jobs WHERE state = $1 ORDER BY id DESC LIMIT $2"
                );
                on_pool!(self, p => sqlx::query_as(&q).bind(s.as_str()).bind(limit).fetch_all(p).await)?
            }
            None => {
                let q = format!("SELECT {COLUMNS} FROM jobs ORDER BY id DESC LIMIT $1");
                on_pool!(self, p => sqlx::query_as(&q).bind(limit).fetch_all(p).await)?
            }
        };
        // A row that cannot be read (a damaged id or state) is left out and logged, not
        // a reason to answer no list at all.
        Ok(rows
            .into_iter()
            .filter_map(|r| {
                r.into_record()
                    .map_err(|e| tracing::warn!("a stored job is left out of a list: {e}"))
                    .ok()
            })
            .collect())
    }

    pub async fn count_by_state(&self) -> Result<Vec<(JobState, i64)>, StoreError> {
        let q = "SELECT state, COUNT(*) FROM jobs GROUP BY state";
        let rows: Vec<(String, i64)> = on_pool!(self, p => sqlx::query_as(q).fetch_all(p).await)?;
        Ok(rows
            .into_iter()
            .filter_map(|(s, n)| JobState::parse(&s).map(|s| (s, n)))
            .collect())
    }

    /// queued → running, with the start time given, counting the attempt (committed
    /// before the render starts: see [`MAX_ATTEMPTS`]); false if the job was no longer
    /// queued.
    pub async fn mark_running_at(&self, id: Uuid, started: &str) -> Result<bool, StoreError> {
        fault::check(fault::Write::Start)?;
        let q = "UPDATE jobs SET state = 'running', started_at = $1, progress = NULL, attempts = attempts + 1 WHERE id = $2 AND state = 'queued'";
        let r = on_pool!(self, p => sqlx::query(q).bind(started).bind(id.to_string()).execute(p).await.map(|r| r.rows_affected()))?;
        Ok(r == 1)
    }

    /// queued → cancelled; false if the job had left `queued`.
    pub async fn cancel_queued(&self, id: Uuid) -> Result<bool, StoreError> {
        fault::check(fault::Write::CancelQueued)?;
        let q = "UPDATE jobs SET state = 'cancelled', finished_at = $1 WHERE id = $2 AND state = 'queued'";
        let r = on_pool!(self, p => sqlx::query(q).bind(now_rfc3339()).bind(id.to_string()).execute(p).await.map(|r| r.rows_affected()))?;
        Ok(r == 1)
    }

    /// Start-up recovery. A job found `running` was interrupted by a crash: if a cancel
    /// was acknowledged for it, it ends `cancelled`; if this was its [`MAX_ATTEMPTS`]th
    /// start, it ends `failed` (a poison job: each run took the server down); otherwise
    /// it goes back to `queued`. Queued jobs with an acknowledged cancel end `cancelled`.
    /// Returns every queued id, oldest first, to be enqueued again; a row whose id is not
    /// a UUID is failed and named in the log, not a reason to refuse to start.
    pub async fn recover(&self) -> Result<Vec<Uuid>, StoreError> {
        fault::check(fault::Write::Recover)?;
        let now = now_rfc3339();
        let q = "UPDATE jobs SET state = 'cancelled', finished_at = $1 WHERE state IN ('queued', 'running') AND cancel_requested = 1";
        on_pool!(self, p => sqlx::query(q).bind(&now).execute(p).await.map(|r| r.rows_affected()))?;
        let poison = JobError::new(
            ErrorCode::Poison,
            format!("the server stopped {MAX_ATTEMPTS} times while rendering this job (a crash or a kill); it is not run again"),
        );
        let q = "UPDATE jobs SET state = 'failed', finished_at = $1, error = $2 WHERE state = 'running' AND attempts >= $3";
        let failed = on_pool!(self, p => sqlx::query(q)
            .bind(&now)
            .bind(column_text(Some(&poison)))
            .bind(i64::from(MAX_ATTEMPTS))
            .execute(p)
            .await
            .map(|r| r.rows_affected()))?;
        if failed > 0 {
            tracing::error!(
                count = failed,
                "poison jobs failed: each of their last {MAX_ATTEMPTS} runs ended with the server"
            );
        }
        let q = "UPDATE jobs SET state = 'queued', started_at = NULL, progress = NULL WHERE state = 'running'";
        on_pool!(self, p => sqlx::query(q).execute(p).await.map(|r| r.rows_affected()))?;
        let q = "SELECT id FROM jobs WHERE state = 'queued' ORDER BY id ASC";
        let ids: Vec<String> = on_pool!(self, p => sqlx::query_scalar(q).fetch_all(p).await)?;
        let mut queued = Vec::with_capacity(ids.len());
        for raw in ids {
            match Uuid::parse_str(&raw) {
                Ok(id) => queued.push(id),
                Err(e) => {
                    tracing::error!(
                        "stored job {:?} has no valid id ({e}); marked failed",
                        clip(&raw)
                    );
                    let q = "UPDATE jobs SET state = 'failed', finished_at = $1 WHERE id = $2";
                    on_pool!(self, p => sqlx::query(q).bind(&now).bind(&raw).execute(p).await.map(|r| r.rows_affected()))?;
                }
            }
        }
        Ok(queued)
    }

    /// Removes a finished job and its images; false if it does not exist or is not finished.
    /// The files go first: on a full disk that frees the space the record's deletion needs
    /// (a record left without its files answers 404 for its frames, and a second DELETE
    /// removes it).
    pub async fn delete_finished(&self, id: Uuid) -> Result<bool, StoreError> {
        let finished = self.get(id).await?.is_some_and(|j| j.state.is_finished());
        if !finished {
            return Ok(false);
        }
        fault::check(fault::Write::RemoveDir)?;
        files::remove_job_dir(&self.job_dir(id)).await?;
        fault::check(fault::Write::Delete)?;
        let q = "DELETE FROM jobs WHERE id = $1 AND state IN ('succeeded', 'failed', 'cancelled')";
        let r = on_pool!(self, p => sqlx::query(q).bind(id.to_string()).execute(p).await.map(|r| r.rows_affected()))?;
        Ok(r == 1)
    }

    /// The folder attempt `token` of job `id` writes its files to (its final image and
    /// layers, its kept iterations, its relayed frames). On a shared database each
    /// attempt has a folder of its own inside the job's, `attempt-<token>`: a worker
    /// presumed dead that wakes up and writes late writes only there, and the end of the
    /// job, checked against the token, records which attempt's folder is the job's
    /// (files cannot check a token themselves). On the embedded store, whose one node
    /// holds every lease it took, it is the job's folder itself.
    #[must_use]
    pub fn attempt_dir(&self, id: Uuid, token: LeaseToken) -> PathBuf {
        if self.is_shared() {
            self.job_dir(id)
                .join(format!("{ATTEMPT_PREFIX}{}", token.0.simple()))
        } else {
            self.job_dir(id)
        }
    }

    /// Where `job`'s files are: its recorded attempt's folder ([`Self::attempt_dir`]), or
    /// the job's folder for a record without a token (the embedded store's, or one
    /// finished before attempts had folders).
    #[must_use]
    pub fn files_dir(&self, job: &JobRecord) -> PathBuf {
        match job.attempt_token {
            Some(token) => self.attempt_dir(job.id, token),
            None => self.job_dir(job.id),
        }
    }

    /// `Err(FilesMissing)` if `job` is finished with a frame but its image file is gone
    /// (removed by hand, a file put where its folder was, a data folder restored without
    /// its `jobs/`): said and logged, rather than answered as a frame without an image
    /// layer. A job that a `DELETE` is removing is the caller's to tell apart.
    pub async fn check_files(&self, job: &JobRecord) -> Result<(), StoreError> {
        if !job.state.is_finished() || !job.has_frame {
            return Ok(());
        }
        let image = self.layer_path(job, Layer::Image, false);
        if files::file_present(&image).await? {
            return Ok(());
        }
        tracing::warn!(id = %job.id, path = %image.display(), "a finished job's files are missing");
        Err(StoreError::FilesMissing(job.id, image))
    }

    /// Path of a stored layer's file of `job`: its PNG, or with `exr` the image's EXR.
    #[must_use]
    pub fn layer_path(&self, job: &JobRecord, layer: Layer, exr: bool) -> PathBuf {
        self.files_dir(job).join(layer.file_name(exr))
    }

    /// Removes what attempt `token` wrote, once its end was refused or its lease lost
    /// (best effort: what is left goes with the job's folder). Nothing on the embedded
    /// store, where the attempt's folder is the job's.
    pub fn discard_attempt_blocking(&self, id: Uuid, token: LeaseToken) {
        if self.is_shared() {
            let _ = std::fs::remove_dir_all(self.attempt_dir(id, token));
        }
    }

    /// Removes the folders of `id`'s other attempts (workers lost before this one), once
    /// this one's end is recorded. Best effort, as [`Self::discard_attempt_blocking`].
    pub fn remove_other_attempts_blocking(&self, id: Uuid, token: LeaseToken) {
        if !self.is_shared() {
            return;
        }
        let keep = self.attempt_dir(id, token);
        let Ok(entries) = std::fs::read_dir(self.job_dir(id)) else {
            return;
        };
        for e in entries.flatten() {
            let name = e.file_name();
            if name.to_string_lossy().starts_with(ATTEMPT_PREFIX) && e.path() != keep {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Failure, StoreError};

    #[test]
    fn a_connection_failure_is_told_from_a_full_disk() {
        let io = |k| StoreError::Io(std::io::Error::from(k));
        assert_eq!(io(std::io::ErrorKind::StorageFull).failure(), Failure::Full);
        let enospc = std::io::Error::from_raw_os_error(28);
        assert_eq!(StoreError::Io(enospc).failure(), Failure::Full);
        assert_eq!(
            StoreError::Db(sqlx::Error::PoolTimedOut).failure(),
            Failure::Unreachable
        );
        let refused = std::io::Error::from(std::io::ErrorKind::ConnectionRefused);
        assert_eq!(
            StoreError::Db(sqlx::Error::Io(refused)).failure(),
            Failure::Unreachable
        );
        assert_eq!(
            io(std::io::ErrorKind::PermissionDenied).failure(),
            Failure::Other
        );
        assert_eq!(
            StoreError::Corrupt(String::new()).failure(),
            Failure::Corrupt
        );
        let gone = StoreError::FilesMissing(uuid::Uuid::nil(), "x/image.png".into());
        assert_eq!(gone.failure(), Failure::FilesMissing);
    }

    #[test]
    fn timestamps_have_fixed_width_so_string_order_is_time_order() {
        let t = time::macros::datetime!(2026-11-25 21:52:06.8 UTC);
        let u = time::macros::datetime!(2026-11-25 21:52:06.82 UTC);
        let (a, b) = (super::rfc3339_millis(t), super::rfc3339_millis(u));
        assert_eq!(a, "2026-11-25T21:52:06.800Z");
        assert_eq!(b, "2026-11-25T21:52:06.820Z");
        assert!(a < b);
        assert_eq!(super::now_rfc3339().len(), a.len());
    }
}
