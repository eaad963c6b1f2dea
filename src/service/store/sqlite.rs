//! The embedded backend: `DIR/glimpse.db`, WAL, every commit synced.

use super::{clip, StoreError};
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::SqlitePool;
use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

/// Opens (creating if missing) `dir/glimpse.db` and runs `migrations/`.
pub(super) async fn open(dir: &Path) -> Result<SqlitePool, StoreError> {
    std::fs::create_dir_all(dir)?;
    let url = format!("sqlite://{}", dir.join("glimpse.db").display());
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
        // A connection still inside a transaction when it comes back (its ROLLBACK
        // failed: see `lease::claim_sqlite`) is closed, never handed out again.
        .after_release(|conn, _| Box::pin(async move { Ok(!super::in_transaction(conn)) }))
        .connect_with(opts)
        .await?;
    refuse_foreign(&pool).await?;
    sqlx::migrate!("./migrations").run(&pool).await?;
    Ok(pool)
}

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
        list(&tables)
    )))
}

/// Up to five quoted names.
pub(super) fn list(names: &[String]) -> String {
    names
        .iter()
        .map(|t| format!("{:?}", clip(t)))
        .take(5)
        .collect::<Vec<_>>()
        .join(", ")
}
