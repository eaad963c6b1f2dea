//! Claims, leases, heartbeats and the reaper: how many workers share one queue
//! (shared/spec/cluster.md "Promises"; the shape of Oban's, River's and graphile-worker's
//! queues). A worker claims the oldest queued job in one statement and holds it under a
//! lease (an expiry on the database's clock, so nodes' clocks need not agree) and an
//! attempt token. Heartbeats push the expiry forward and return whether a cancel was
//! asked; every write of the worker names its token, so once its lease has expired and
//! the job went elsewhere (the reaper requeued it, another worker claimed it) the late
//! writes of the presumed-dead worker change nothing. Any node may reap: every
//! statement of [`Store::reap`] is conditional on the expiry, so running it twice, or
//! on two nodes at once, changes nothing more.

use super::fault;
use super::record::column_text;
use super::{now_rfc3339, JobError, JobState, Pool, Progress, Store, StoreError};
use crate::progressive::RenderStats;
use crate::service::error_code::ErrorCode;
use std::time::Duration;
use uuid::Uuid;

/// Attempts a job gets in a cluster: its third worker lost is its last (cluster.md:
/// "after a bounded number of attempts it is `failed` with the reason").
pub const MAX_LEASE_ATTEMPTS: u32 = 3;

/// The attempt token of a claim: a fresh UUIDv7 (74 random bits), unique per attempt.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LeaseToken(pub Uuid);

/// A job claimed by a worker.
#[derive(Clone, Debug)]
pub struct Claim {
    pub id: Uuid,
    /// 1 for the first run, 2 after the first worker was lost, ...
    pub attempt: u32,
    pub token: LeaseToken,
    pub started_at: String,
}

/// What a heartbeat learned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Beat {
    /// The lease is extended; a cancel was asked if `cancel_requested`.
    Held { cancel_requested: bool },
    /// The lease is gone (expired and reaped, or the job finished elsewhere): stop
    /// rendering, write nothing more.
    Lost,
}

/// What one pass of the reaper did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Reaped {
    pub requeued: u64,
    pub failed: u64,
    pub cancelled: u64,
}

/// The claim's `started_at`: the claimer's clock (`$1`), but never before the job's
/// `created_at`. The claimer reads its clock before its connection is free, and the job it
/// gets may have been inserted in that gap; both are fixed-width RFC 3339, so text order is
/// time order.
const NOT_BEFORE_CREATION: &str = "CASE WHEN created_at > $1 THEN created_at ELSE $1 END";

/// The claim on SQLite: `q` in a `BEGIN IMMEDIATE` transaction on a connection of its
/// own, which is closed rather than given back to the pool if anything in the transaction
/// fails. On a full disk SQLite may roll the transaction back by itself when the UPDATE
/// or the COMMIT fails (sqlite.org/lang_transaction.html, "Response To Errors Within A
/// Transaction"); sqlx's own ROLLBACK then fails too and leaves the connection counted
/// at a non-zero transaction depth, and every later `BEGIN` on it fails with "attempted
/// to call begin_with at non-zero transaction depth": back in the pool, such connections
/// stopped every claim for good, long after space returned (measured before: five
/// queued jobs never started, `/healthz` 503 for minutes). The injected `store.start`
/// fault fails the COMMIT in just that way.
async fn claim_sqlite(
    p: &sqlx::SqlitePool,
    q: &str,
    (started, worker, token, lease_ms): (&str, Option<&str>, String, i64),
) -> Result<Option<(String, i64, String)>, StoreError> {
    use sqlx::Connection as _;
    let mut conn = p.acquire().await?;
    let run = async {
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let row = sqlx::query_as(q)
            .bind(started)
            .bind(worker)
            .bind(token)
            .bind(lease_ms)
            .fetch_optional(&mut *tx)
            .await?;
        if let Err(e) = fault::check(fault::Write::Start) {
            // As SQLite on SQLITE_FULL at COMMIT: the transaction is gone, the error
            // reported; the `Transaction` below does not know it.
            sqlx::query("ROLLBACK").execute(&mut *tx).await?;
            return Err(e.into());
        }
        tx.commit().await?;
        Ok::<_, StoreError>(row)
    };
    let row = run.await;
    if row.is_err() {
        conn.close_on_drop();
    }
    row
}

impl Store {
    /// The database's clock in milliseconds since the Unix epoch, as SQL.
    fn now_ms(&self) -> &'static str {
        match self.pool {
            Pool::Sqlite(_) => "CAST((julianday('now') - 2440587.5) * 86400000 AS INTEGER)",
            Pool::Postgres(_) => "CAST(EXTRACT(EPOCH FROM clock_timestamp()) * 1000 AS BIGINT)",
        }
    }

    /// Claims the oldest queued job for `worker` under a lease of `lease`; `None` if no
    /// job is waiting. `worker` is `None` on the embedded store's one node (the job
    /// object's `worker` stays null there). One statement: on PostgreSQL the row is picked `FOR UPDATE SKIP
    /// LOCKED` (two workers never wait on nor take the same job); SQLite has one writer
    /// and the statement runs in a `BEGIN IMMEDIATE` transaction, which takes the write
    /// lock before the job is read.
    pub async fn claim(
        &self,
        worker: Option<&str>,
        lease: Duration,
    ) -> Result<Option<Claim>, StoreError> {
        if self.is_shared() {
            // On SQLite the fault strikes inside the transaction ([`claim_sqlite`]).
            fault::check(fault::Write::Start)?;
        }
        let started = now_rfc3339();
        let token = LeaseToken(Uuid::now_v7());
        let set = format!(
            "state = 'running', started_at = {}, progress = NULL, attempts = attempts + 1, worker = $2, lease_token = $3, lease_expires_at = {} + $4",
            NOT_BEFORE_CREATION,
            self.now_ms()
        );
        let lease_ms = i64::try_from(lease.as_millis()).unwrap_or(i64::MAX / 2);
        let row: Option<(String, i64, String)> = match &self.pool {
            Pool::Postgres(p) => {
                let q = format!(
                    "WITH next AS (SELECT id FROM jobs WHERE state = 'queued' AND cancel_requested = 0 ORDER BY id LIMIT 1 FOR UPDATE SKIP LOCKED) \
                     UPDATE jobs SET {} FROM next WHERE jobs.id = next.id RETURNING jobs.id, jobs.attempts, jobs.started_at",
                    set.replace("attempts = attempts", "attempts = jobs.attempts")
                );
                sqlx::query_as(&q)
                    .bind(&started)
                    .bind(worker)
                    .bind(token.0.to_string())
                    .bind(lease_ms)
                    .fetch_optional(p)
                    .await?
            }
            Pool::Sqlite(p) => {
                let q = format!(
                    "UPDATE jobs SET {set} WHERE id = (SELECT id FROM jobs WHERE state = 'queued' AND cancel_requested = 0 ORDER BY id LIMIT 1) RETURNING id, attempts, started_at"
                );
                let binds = (started.as_str(), worker, token.0.to_string(), lease_ms);
                claim_sqlite(p, &q, binds).await?
            }
        };
        let Some((id, attempts, started)) = row else {
            return Ok(None);
        };
        let id = Uuid::parse_str(&id)
            .map_err(|e| StoreError::Corrupt(format!("claimed job id {id:?}: {e}")))?;
        Ok(Some(Claim {
            id,
            attempt: u32::try_from(attempts).unwrap_or(u32::MAX),
            token,
            started_at: started,
        }))
    }

    /// Extends the lease of `id` held with `token` by `lease` from now, storing the
    /// render's `progress` (so every node shows it); whether the lease is still held.
    pub async fn heartbeat(
        &self,
        id: Uuid,
        token: LeaseToken,
        lease: Duration,
        progress: Option<&Progress>,
    ) -> Result<Beat, StoreError> {
        fault::check(fault::Write::Heartbeat)?;
        let q = format!(
            "UPDATE jobs SET lease_expires_at = {} + $1, progress = COALESCE($2, progress) \
             WHERE id = $3 AND lease_token = $4 AND state = 'running' RETURNING cancel_requested",
            self.now_ms()
        );
        let lease_ms = i64::try_from(lease.as_millis()).unwrap_or(i64::MAX / 2);
        let flag: Option<i64> = on_pool!(self, p => sqlx::query_scalar(&q)
            .bind(lease_ms)
            .bind(column_text(progress))
            .bind(id.to_string())
            .bind(token.0.to_string())
            .fetch_optional(p)
            .await)?;
        Ok(match flag {
            Some(c) => Beat::Held {
                cancel_requested: c != 0,
            },
            None => Beat::Lost,
        })
    }

    /// running → a finished state, by the worker holding the lease; `None` (nothing
    /// written) if `token` no longer holds it. The token stays in the row: on a shared
    /// database it says which attempt's files are the job's ([`Store::files_dir`]), so
    /// the end and the files it names are one token-checked write.
    #[allow(clippy::too_many_arguments)] // one column each, named at the call
    pub async fn finish_leased(
        &self,
        id: Uuid,
        token: LeaseToken,
        state: JobState,
        progress: Option<&Progress>,
        stats: Option<&RenderStats>,
        error: Option<&JobError>,
        has_frame: bool,
    ) -> Result<Option<String>, StoreError> {
        fault::check(fault::Write::Finish)?;
        let finished = now_rfc3339();
        let q = "UPDATE jobs SET state = $1, finished_at = $2, progress = $3, stats = $4, error = $5, has_frame = $6, lease_expires_at = NULL \
                 WHERE id = $7 AND lease_token = $8 AND state = 'running'";
        let n = on_pool!(self, p => sqlx::query(q)
            .bind(state.as_str())
            .bind(&finished)
            .bind(column_text(progress))
            .bind(column_text(stats))
            .bind(column_text(error))
            .bind(i64::from(has_frame))
            .bind(id.to_string())
            .bind(token.0.to_string())
            .execute(p)
            .await
            .map(|r| r.rows_affected()))?;
        Ok((n == 1).then_some(finished))
    }

    /// running → queued by the worker holding the lease (it is shutting down): the
    /// interrupted attempt does not count. False if the lease was already lost.
    pub async fn release(&self, id: Uuid, token: LeaseToken) -> Result<bool, StoreError> {
        fault::check(fault::Write::Requeue)?;
        let q = "UPDATE jobs SET state = 'queued', started_at = NULL, progress = NULL, lease_token = NULL, lease_expires_at = NULL, \
                 attempts = CASE WHEN attempts > 0 THEN attempts - 1 ELSE 0 END \
                 WHERE id = $1 AND lease_token = $2 AND state = 'running'";
        let n = on_pool!(self, p => sqlx::query(q)
            .bind(id.to_string())
            .bind(token.0.to_string())
            .execute(p)
            .await
            .map(|r| r.rows_affected()))?;
        Ok(n == 1)
    }

    /// One pass of the reaper: every running job whose lease has expired (its worker is
    /// presumed dead) ends `cancelled` if a cancel was asked, `failed` with the reason
    /// after `max_attempts` attempts, and otherwise goes back to `queued` for another
    /// worker. Idempotent, and safe on any number of nodes at once.
    pub async fn reap(&self, max_attempts: u32) -> Result<Reaped, StoreError> {
        fault::check(fault::Write::Reap)?;
        let now = now_rfc3339();
        let expired = format!("state = 'running' AND lease_expires_at < {}", self.now_ms());
        let clear = "lease_token = NULL, lease_expires_at = NULL";
        let q = format!("UPDATE jobs SET state = 'cancelled', finished_at = $1, {clear} WHERE {expired} AND cancel_requested = 1");
        let cancelled = on_pool!(self, p => sqlx::query(&q).bind(&now).execute(p).await.map(|r| r.rows_affected()))?;
        let reason = JobError::new(
            ErrorCode::Poison,
            format!("each of its {max_attempts} attempts ended with its worker gone (killed, crashed or cut off from the database); it is not run again"),
        );
        let q = format!("UPDATE jobs SET state = 'failed', finished_at = $1, error = $2, {clear} WHERE {expired} AND attempts >= $3");
        let failed = on_pool!(self, p => sqlx::query(&q)
            .bind(&now)
            .bind(column_text(Some(&reason)))
            .bind(i64::from(max_attempts))
            .execute(p)
            .await
            .map(|r| r.rows_affected()))?;
        let q = format!("UPDATE jobs SET state = 'queued', started_at = NULL, progress = NULL, {clear} WHERE {expired}");
        let requeued =
            on_pool!(self, p => sqlx::query(&q).execute(p).await.map(|r| r.rows_affected()))?;
        Ok(Reaped {
            requeued,
            failed,
            cancelled,
        })
    }

    /// Jobs waiting for a worker (the cluster's queue depth: `429` beyond the capacity).
    pub async fn queued_count(&self) -> Result<i64, StoreError> {
        let q = "SELECT COUNT(*) FROM jobs WHERE state = 'queued'";
        Ok(on_pool!(self, p => sqlx::query_scalar(q).fetch_one(p).await)?)
    }
}
