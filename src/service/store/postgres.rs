//! The shared backend: one PostgreSQL database for every API and worker node
//! (shared/spec/cluster.md), `migrations/postgres/`.

use super::StoreError;
use sqlx::postgres::{PgConnectOptions, PgPoolOptions};
use sqlx::PgPool;
use std::str::FromStr;
use std::time::Duration;

/// Connections per node: the API's requests and the local workers' writes; a farm of
/// dozens of nodes stays well under PostgreSQL's default of 100.
const MAX_CONNECTIONS: u32 = 8;

/// How long a request waits for a connection (or the database) before it fails with
/// `503 database_unreachable`. A client is told at once, within the `/healthz` ping's 2 s,
/// rather than after 10 s (measured before with the database down: every POST and GET
/// took 10 s to fail); a database restart of a few seconds is ridden out by the clients'
/// retries (`Retry-After`) and the workers' own, which retry every write until it lands.
const ACQUIRE_TIMEOUT: Duration = Duration::from_millis(1500);

/// Connects to `url` and runs `migrations/postgres/` (sqlx takes an advisory lock, so
/// nodes starting together migrate once).
pub(super) async fn open(url: &str) -> Result<PgPool, StoreError> {
    let opts = PgConnectOptions::from_str(url)?.application_name("glimpse");
    let pool = PgPoolOptions::new()
        .max_connections(MAX_CONNECTIONS)
        // A connection still inside a transaction when it comes back (its ROLLBACK
        // failed: see `lease::claim_sqlite`) is closed, never handed out again.
        .after_release(|conn, _| Box::pin(async move { Ok(!super::in_transaction(conn)) }))
        .acquire_timeout(ACQUIRE_TIMEOUT)
        // A connection broken by a database restart is found out before it is used.
        .test_before_acquire(true)
        .connect_with(opts)
        .await?;
    refuse_foreign(&pool).await?;
    sqlx::migrate!("./migrations/postgres").run(&pool).await?;
    Ok(pool)
}

/// Refuses a database whose `public` schema holds tables but never ran our migrations.
async fn refuse_foreign(pool: &PgPool) -> Result<(), StoreError> {
    let tables: Vec<String> = sqlx::query_scalar(
        "SELECT table_name::text FROM information_schema.tables WHERE table_schema = 'public'",
    )
    .fetch_all(pool)
    .await?;
    if tables.is_empty() || tables.iter().any(|t| t == "_sqlx_migrations") {
        return Ok(());
    }
    Err(StoreError::Corrupt(format!(
        "the database is not a Glimpse job store (it holds the tables {}); name another database",
        super::sqlite::list(&tables)
    )))
}

/// `url` with its password replaced by `***` (logs and messages never show it).
pub(super) fn without_password(url: &str) -> String {
    match PgConnectOptions::from_str(url) {
        Ok(_) => match url.split_once("://") {
            Some((scheme, rest)) => match rest.split_once('@') {
                Some((user, host)) => match user.split_once(':') {
                    Some((name, _)) => format!("{scheme}://{name}:***@{host}"),
                    None => url.to_owned(),
                },
                None => url.to_owned(),
            },
            None => url.to_owned(),
        },
        Err(_) => "postgres://(unreadable URL)".to_owned(),
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_password_never_shows() {
        assert_eq!(
            super::without_password("postgres://glimpse:secret@db:5432/jobs"),
            "postgres://glimpse:***@db:5432/jobs"
        );
        assert_eq!(
            super::without_password("postgres://glimpse@db/jobs"),
            "postgres://glimpse@db/jobs"
        );
    }
}
