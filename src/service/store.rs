//! Durable job records (SQLite through sqlx, WAL mode) and the final images beside them.
//!
//! Layout under the data folder:
//! - `glimpse.db` (+ `-wal`, `-shm`): the `jobs` table of `migrations/0001_init.sql`;
//! - `jobs/<id>/{image,samples,distance,classes}.png` and `jobs/<id>/image.exr`: the last
//!   frame of a finished (or cancelled) job. File names derive from the job id only (a
//!   parsed UUID), never from user input, so no request can choose a path.
//!
//! service-api.md "Durability": a job is inserted (and the transaction committed with
//! `synchronous = FULL`) before the `201` leaves; at start-up [`Store::recover`] puts jobs
//! found `running` back to `queued`. At a job's end, `image.png` is written and synced,
//! then the record is committed, then `done` goes out; the other layers and the EXR are
//! written after (`jobs.rs`), so a crash in between leaves a finished job with its
//! state, statistics and image, whose other layers answer 404.

use serde::Serialize;
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::SqlitePool;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Duration;
use uuid::Uuid;

/// The five states of service-api.md.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    Queued,
    Running,
    Succeeded,
    Failed,
    Cancelled,
}

impl JobState {
    pub const ALL: [JobState; 5] = [
        JobState::Queued,
        JobState::Running,
        JobState::Succeeded,
        JobState::Failed,
        JobState::Cancelled,
    ];

    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Succeeded => "succeeded",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }

    #[must_use]
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|st| st.as_str() == s)
    }

    /// Succeeded, failed or cancelled: nothing will change any more.
    #[must_use]
    pub fn is_finished(self) -> bool {
        matches!(
            self,
            JobState::Succeeded | JobState::Failed | JobState::Cancelled
        )
    }
}

/// One job as the API shows it (the scene document is kept in the store but not echoed).
#[derive(Clone, Debug, Serialize)]
pub struct JobRecord {
    pub id: Uuid,
    pub state: JobState,
    pub name: String,
    pub created_at: String,
    pub started_at: Option<String>,
    pub finished_at: Option<String>,
    pub progress: Option<serde_json::Value>,
    pub stats: Option<serde_json::Value>,
    pub error: Option<serde_json::Value>,
    /// True once a frame was stored on disk (`GET .../frame` can answer after a restart).
    #[serde(skip)]
    pub has_frame: bool,
}

#[derive(sqlx::FromRow)]
struct Row {
    id: String,
    name: String,
    state: String,
    created_at: String,
    started_at: Option<String>,
    finished_at: Option<String>,
    progress: Option<String>,
    stats: Option<String>,
    error: Option<String>,
    has_frame: i64,
}

const COLUMNS: &str =
    "id, name, state, created_at, started_at, finished_at, progress, stats, error, has_frame";

impl Row {
    fn into_record(self) -> Result<JobRecord, StoreError> {
        let id = Uuid::parse_str(&self.id).map_err(|e| {
            StoreError::Corrupt(format!("job id {:?} is not a UUID: {e}", clip(&self.id)))
        })?;
        // A damaged JSON column loses that field (logged), not the job, nor every list
        // that includes it.
        let json = |column: &str, s: Option<String>| -> Option<serde_json::Value> {
            let s = s?;
            serde_json::from_str(&s)
                .map_err(
                    |e| tracing::warn!(%id, "the stored {column} is not JSON ({e}); shown as null"),
                )
                .ok()
        };
        Ok(JobRecord {
            id,
            state: JobState::parse(&self.state).ok_or_else(|| {
                StoreError::Corrupt(format!(
                    "job {id} has the unknown state {:?}",
                    clip(&self.state)
                ))
            })?,
            progress: json("progress", self.progress),
            stats: json("stats", self.stats),
            error: json("error", self.error),
            name: self.name,
            created_at: self.created_at,
            started_at: self.started_at,
            finished_at: self.finished_at,
            has_frame: self.has_frame != 0,
        })
    }
}

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
}

/// At most 64 characters of `s` (with "…" when cut), for messages that quote stored or
/// client-sent text.
#[must_use]
pub fn clip(s: &str) -> String {
    match s.char_indices().nth(64) {
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

/// Starts of a job after which a crash during its render makes it a poison job (failed at
/// the next start-up instead of run again): two, so that one unrelated crash (a power cut,
/// an operator's kill) does not fail a good job.
pub const MAX_ATTEMPTS: u32 = 2;

/// Refuses a database that is not ours: one that has tables but never ran our migrations
/// (a `glimpse.db` of some other program, or a data folder pointed at the wrong place).
async fn refuse_foreign(pool: &SqlitePool) -> Result<(), StoreError> {
    let tables: Vec<String> = sqlx::query_scalar(
        "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%'",
    )
    .fetch_all(pool)
    .await?;
    if tables.is_empty() || tables.iter().any(|t| t == "_sqlx_migrations") {
        return Ok(());
    }
    Err(StoreError::Corrupt(format!(
        "glimpse.db is not a Glimpse job store (it holds the tables {}); use another --data folder",
        tables
            .iter()
            .map(|t| format!("{:?}", clip(t)))
            .take(5)
            .collect::<Vec<_>>()
            .join(", ")
    )))
}

/// Names of the stored layer files; `image.exr` is the linear HDR image.
pub const LAYER_FILES: [&str; 5] = ["image", "samples", "distance", "classes", "objects"];

#[derive(Clone, Debug)]
pub struct Store {
    pool: SqlitePool,
    jobs_dir: PathBuf,
}

impl Store {
    /// Opens (creating if missing) `data_dir/glimpse.db` and runs the migrations.
    pub async fn open(data_dir: &Path) -> Result<Self, StoreError> {
        std::fs::create_dir_all(data_dir)?;
        let jobs_dir = data_dir.join("jobs");
        std::fs::create_dir_all(&jobs_dir)?;
        let url = format!("sqlite://{}", data_dir.join("glimpse.db").display());
        let opts = SqliteConnectOptions::from_str(&url)?
            .create_if_missing(true)
            // WAL: readers (GET /v1/jobs) never wait for the worker's writes.
            .journal_mode(SqliteJournalMode::Wal)
            // FULL: a commit is on disk before we answer 201 (durability contract).
            .synchronous(SqliteSynchronous::Full)
            .busy_timeout(Duration::from_secs(5))
            .foreign_keys(true);
        let pool = SqlitePoolOptions::new()
            .max_connections(4)
            .connect_with(opts)
            .await?;
        refuse_foreign(&pool).await?;
        sqlx::migrate!("./migrations").run(&pool).await?;
        Ok(Self { pool, jobs_dir })
    }

    /// Marks a queued or running job's cancel request durably (before its `202`); false
    /// if the job is not queued or running any more.
    pub async fn request_cancel(&self, id: Uuid) -> Result<bool, StoreError> {
        let r = sqlx::query(
            "UPDATE jobs SET cancel_requested = 1 WHERE id = ? AND state IN ('queued', 'running')",
        )
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    pub async fn close(&self) {
        self.pool.close().await;
    }

    /// Folder of a job's images. `id` is a parsed UUID, so the path cannot escape.
    #[must_use]
    pub fn job_dir(&self, id: Uuid) -> PathBuf {
        self.jobs_dir.join(id.hyphenated().to_string())
    }

    pub async fn insert(&self, id: Uuid, name: &str, scene: &str) -> Result<JobRecord, StoreError> {
        let created = now_rfc3339();
        sqlx::query(
            "INSERT INTO jobs (id, name, state, scene, created_at) VALUES (?, ?, 'queued', ?, ?)",
        )
        .bind(id.to_string())
        .bind(name)
        .bind(scene)
        .bind(&created)
        .execute(&self.pool)
        .await?;
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
            has_frame: false,
        })
    }

    pub async fn get(&self, id: Uuid) -> Result<Option<JobRecord>, StoreError> {
        let row: Option<Row> = sqlx::query_as(&format!("SELECT {COLUMNS} FROM jobs WHERE id = ?"))
            .bind(id.to_string())
            .fetch_optional(&self.pool)
            .await?;
        row.map(Row::into_record).transpose()
    }

    /// Every finished job's id and finishing time (RFC 3339), newest first: what
    /// retention (`service::retention`) weighs.
    pub async fn finished(&self) -> Result<Vec<(String, Option<String>)>, StoreError> {
        Ok(sqlx::query_as(
            "SELECT id, finished_at FROM jobs WHERE state IN ('succeeded', 'failed', 'cancelled') ORDER BY id DESC",
        )
        .fetch_all(&self.pool)
        .await?)
    }

    pub async fn scene(&self, id: Uuid) -> Result<Option<String>, StoreError> {
        Ok(sqlx::query_scalar("SELECT scene FROM jobs WHERE id = ?")
            .bind(id.to_string())
            .fetch_optional(&self.pool)
            .await?)
    }

    /// Newest first (UUIDv7 ids sort by creation time).
    pub async fn list(
        &self,
        state: Option<JobState>,
        limit: u32,
    ) -> Result<Vec<JobRecord>, StoreError> {
        let rows: Vec<Row> = match state {
            Some(s) => {
                sqlx::query_as(&format!(
                    "SELECT {COLUMNS} FROM jobs WHERE state = ? ORDER BY id DESC LIMIT ?"
                ))
                .bind(s.as_str())
                .bind(i64::from(limit))
                .fetch_all(&self.pool)
                .await?
            }
            None => {
                sqlx::query_as(&format!(
                    "SELECT {COLUMNS} FROM jobs ORDER BY id DESC LIMIT ?"
                ))
                .bind(i64::from(limit))
                .fetch_all(&self.pool)
                .await?
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
        let rows: Vec<(String, i64)> =
            sqlx::query_as("SELECT state, COUNT(*) FROM jobs GROUP BY state")
                .fetch_all(&self.pool)
                .await?;
        Ok(rows
            .into_iter()
            .filter_map(|(s, n)| JobState::parse(&s).map(|s| (s, n)))
            .collect())
    }

    /// queued → running; false if the job was no longer queued (cancelled meanwhile).
    pub async fn mark_running(&self, id: Uuid) -> Result<Option<String>, StoreError> {
        let started = now_rfc3339();
        Ok(self.mark_running_at(id, &started).await?.then_some(started))
    }

    /// [`Self::mark_running`] with the start time given, counting the attempt (committed
    /// before the render starts: see [`MAX_ATTEMPTS`]); false if the job was no longer
    /// queued.
    pub async fn mark_running_at(&self, id: Uuid, started: &str) -> Result<bool, StoreError> {
        let r = sqlx::query(
            "UPDATE jobs SET state = 'running', started_at = ?, progress = NULL, attempts = attempts + 1 WHERE id = ? AND state = 'queued'",
        )
        .bind(started)
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// queued → cancelled; false if the job had left `queued`.
    pub async fn cancel_queued(&self, id: Uuid) -> Result<bool, StoreError> {
        let r = sqlx::query(
            "UPDATE jobs SET state = 'cancelled', finished_at = ? WHERE id = ? AND state = 'queued'",
        )
        .bind(now_rfc3339())
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// running → a finished state, with what the render left.
    pub async fn finish(
        &self,
        id: Uuid,
        state: JobState,
        progress: Option<&serde_json::Value>,
        stats: Option<&serde_json::Value>,
        error: Option<&serde_json::Value>,
        has_frame: bool,
    ) -> Result<String, StoreError> {
        let finished = now_rfc3339();
        sqlx::query(
            "UPDATE jobs SET state = ?, finished_at = ?, progress = ?, stats = ?, error = ?, has_frame = ? WHERE id = ?",
        )
        .bind(state.as_str())
        .bind(&finished)
        .bind(progress.map(ToString::to_string))
        .bind(stats.map(ToString::to_string))
        .bind(error.map(ToString::to_string))
        .bind(i64::from(has_frame))
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(finished)
    }

    /// running → queued (graceful shutdown: the job runs again from the start next time;
    /// the interrupted attempt does not count against it).
    pub async fn requeue(&self, id: Uuid) -> Result<(), StoreError> {
        sqlx::query(
            "UPDATE jobs SET state = 'queued', started_at = NULL, progress = NULL, attempts = MAX(attempts - 1, 0) WHERE id = ? AND state = 'running'",
        )
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Start-up recovery. A job found `running` was interrupted by a crash: if a cancel
    /// was acknowledged for it, it ends `cancelled`; if this was its [`MAX_ATTEMPTS`]th
    /// start, it ends `failed` (a poison job: each run took the server down); otherwise
    /// it goes back to `queued`. Queued jobs with an acknowledged cancel end `cancelled`.
    /// Returns every queued id, oldest first, to be enqueued again; a row whose id is not
    /// a UUID is failed and named in the log, not a reason to refuse to start.
    pub async fn recover(&self) -> Result<Vec<Uuid>, StoreError> {
        let now = now_rfc3339();
        sqlx::query("UPDATE jobs SET state = 'cancelled', finished_at = ? WHERE state IN ('queued', 'running') AND cancel_requested = 1")
            .bind(&now)
            .execute(&self.pool)
            .await?;
        let poison = serde_json::json!({
            "code": "poison",
            "message": format!("the server stopped {MAX_ATTEMPTS} times while rendering this job (a crash or a kill); it is not run again"),
        });
        let failed = sqlx::query("UPDATE jobs SET state = 'failed', finished_at = ?, error = ? WHERE state = 'running' AND attempts >= ?")
            .bind(&now)
            .bind(poison.to_string())
            .bind(i64::from(MAX_ATTEMPTS))
            .execute(&self.pool)
            .await?;
        if failed.rows_affected() > 0 {
            tracing::error!(
                count = failed.rows_affected(),
                "poison jobs failed: each of their last {MAX_ATTEMPTS} runs ended with the server"
            );
        }
        sqlx::query("UPDATE jobs SET state = 'queued', started_at = NULL, progress = NULL WHERE state = 'running'")
            .execute(&self.pool)
            .await?;
        let ids: Vec<String> =
            sqlx::query_scalar("SELECT id FROM jobs WHERE state = 'queued' ORDER BY id ASC")
                .fetch_all(&self.pool)
                .await?;
        let mut queued = Vec::with_capacity(ids.len());
        for raw in ids {
            match Uuid::parse_str(&raw) {
                Ok(id) => queued.push(id),
                Err(e) => {
                    tracing::error!(
                        "stored job {:?} has no valid id ({e}); marked failed",
                        clip(&raw)
                    );
                    sqlx::query("UPDATE jobs SET state = 'failed', finished_at = ? WHERE id = ?")
                        .bind(&now)
                        .bind(&raw)
                        .execute(&self.pool)
                        .await?;
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
        let dir = self.job_dir(id);
        match tokio::fs::remove_dir_all(&dir).await {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(e.into()),
        }
        let r = sqlx::query(
            "DELETE FROM jobs WHERE id = ? AND state IN ('succeeded', 'failed', 'cancelled')",
        )
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// Path of a stored layer (`image`, ...) as PNG, or of the EXR image.
    #[must_use]
    pub fn layer_path(&self, id: Uuid, layer: &str, exr: bool) -> Option<PathBuf> {
        let name = LAYER_FILES.iter().find(|l| **l == layer)?;
        let file = if exr {
            format!("{name}.exr")
        } else {
            format!("{name}.png")
        };
        Some(self.job_dir(id).join(file))
    }
}

/// The file the final image goes to, created empty while the job renders (see
/// [`prepare_job_dir_blocking`]).
pub const FINAL_IMAGE_FILE: &str = "image.png";

/// Creates a job's folder and an empty [`FINAL_IMAGE_FILE`] in it, and makes both names
/// durable (the folder is synced for the file, `jobs/` for the folder). Called while the
/// job renders, so that at its end storing the final image costs one write and one data
/// sync, not also a rename and the folder's sync (each sync ~4 ms on the test machine,
/// on the path between a render's end and its `done`). The empty file is never served:
/// the record says `has_frame` only after the image is written into it.
pub fn prepare_job_dir_blocking(dir: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    std::fs::File::create(dir.join(FINAL_IMAGE_FILE))?;
    std::fs::File::open(dir)?.sync_all()?;
    match dir.parent() {
        Some(parent) => std::fs::File::open(parent)?.sync_all(),
        None => Ok(()),
    }
}

/// Writes the final image into the file [`prepare_job_dir_blocking`] made and syncs its
/// data (with its length): after this returns, the bytes survive a crash. Falls back to
/// [`write_files_blocking`] (temp file, rename, folder sync) if that file is missing.
///
/// Overwriting in place is safe here although it is not atomic: the file is written once
/// per run of a job, before the record says `has_frame`; a crash during the write leaves
/// a job that is not finished in the store, so it runs again and nobody reads the file.
pub fn write_final_image_blocking(dir: &Path, png: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    match std::fs::OpenOptions::new()
        .write(true)
        .truncate(true)
        .open(dir.join(FINAL_IMAGE_FILE))
    {
        Ok(mut f) => {
            f.write_all(png)?;
            f.sync_data()
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            write_files_blocking(dir, &[(FINAL_IMAGE_FILE.to_owned(), png.to_vec())])
        }
        Err(e) => Err(e),
    }
}

/// Writes `files` (name, bytes) into `dir` atomically (temp file + rename), synchronously:
/// called from worker threads, never from the async runtime.
pub fn write_files_blocking<B: AsRef<[u8]> + Sync>(
    dir: &Path,
    files: &[(String, B)],
) -> std::io::Result<()> {
    use rayon::prelude::*;
    use std::io::Write;
    if !dir.exists() {
        std::fs::create_dir_all(dir)?;
        // The folder's own name must survive a crash too, not only the files in it.
        if let Some(parent) = dir.parent() {
            std::fs::File::open(parent)?.sync_all()?;
        }
    }
    // Each file is written to a temporary name and synced before it is renamed into place,
    // so a crash leaves either the old file or the whole new one. The files are written
    // and synced in parallel (the syncs wait on the disk, not the CPU: one at a time they
    // were most of the time between a render's end and its `done`), then the folder is
    // synced so the renames themselves survive a crash.
    files.par_iter().try_for_each(|(name, bytes)| {
        let tmp = dir.join(format!(".{name}.tmp"));
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes.as_ref())?;
        f.sync_all()
    })?;
    for (name, _) in files {
        std::fs::rename(dir.join(format!(".{name}.tmp")), dir.join(name))?;
    }
    std::fs::File::open(dir)?.sync_all()
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_final_image_overwrites_its_placeholder_or_is_written_without_one() {
        let dir = tempfile::tempdir().unwrap();
        // Prepared: the (empty) placeholder is overwritten; a longer earlier content (a
        // re-run after a crash) is truncated, not left as a tail.
        let job = dir.path().join("prepared");
        super::prepare_job_dir_blocking(&job).unwrap();
        let file = job.join(super::FINAL_IMAGE_FILE);
        assert_eq!(std::fs::read(&file).unwrap(), b"");
        std::fs::write(&file, b"an older and longer image").unwrap();
        super::write_final_image_blocking(&job, b"png").unwrap();
        assert_eq!(std::fs::read(&file).unwrap(), b"png");
        // Not prepared (the preparation failed): the folder is made and the file written
        // by temp file and rename, with no temp file left behind.
        let job = dir.path().join("unprepared");
        super::write_final_image_blocking(&job, b"png2").unwrap();
        assert_eq!(
            std::fs::read(job.join(super::FINAL_IMAGE_FILE)).unwrap(),
            b"png2"
        );
        let names: Vec<_> = std::fs::read_dir(&job)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, [super::FINAL_IMAGE_FILE]);
        // A folder that cannot be made is an error, not a panic.
        let blocked = dir.path().join("a-file");
        std::fs::write(&blocked, b"x").unwrap();
        assert!(super::write_final_image_blocking(&blocked.join("job"), b"png").is_err());
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
