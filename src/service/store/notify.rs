//! News between nodes through PostgreSQL's `LISTEN`/`NOTIFY`, to hasten what every node
//! also finds by polling (shared/spec/cluster.md): a job became claimable, a running
//! job's progress (and so its relayed frame) moved. Notifications sent while a node's
//! listening connection is down are lost, so they only shorten waits; the polls stay.
//! Nothing on the embedded store, whose one node wakes its own workers.

use super::{Pool, Store, StoreError};
use sqlx::postgres::PgListener;
use uuid::Uuid;

/// A job was queued (submitted, reaped, released): idle workers may claim it.
const QUEUED: &str = "glimpse_queued";
/// A running job's progress was stored with a new frame; the payload is its id.
const PROGRESS: &str = "glimpse_progress";

/// What a node hears.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum News {
    Queued,
    Progress(Uuid),
}

/// A node's listening connection.
pub struct Listener(PgListener);

impl Store {
    /// Tells every listening node `news` (after the write it reports is committed). A
    /// failure is only logged: the listeners' polls find the same a little later.
    pub async fn announce(&self, news: News) {
        let Pool::Postgres(p) = &self.pool else {
            return;
        };
        let (channel, payload) = match news {
            News::Queued => (QUEUED, String::new()),
            News::Progress(id) => (PROGRESS, id.to_string()),
        };
        let r = sqlx::query("SELECT pg_notify($1, $2)")
            .bind(channel)
            .bind(payload)
            .execute(p)
            .await;
        if let Err(e) = r {
            tracing::debug!("NOTIFY {channel}: {e}");
        }
    }

    /// A connection that hears every node's [`News`]; `None` on the embedded store.
    pub async fn listen(&self) -> Result<Option<Listener>, StoreError> {
        let Pool::Postgres(p) = &self.pool else {
            return Ok(None);
        };
        let mut l = PgListener::connect_with(p).await?;
        l.listen_all([QUEUED, PROGRESS]).await?;
        Ok(Some(Listener(l)))
    }
}

impl Listener {
    /// The next news; an error when the database is away (the connection is made again
    /// at the next call, and what was sent meanwhile is lost).
    pub async fn next(&mut self) -> Result<News, StoreError> {
        loop {
            let n = self.0.recv().await?;
            match n.channel() {
                QUEUED => return Ok(News::Queued),
                PROGRESS => {
                    if let Ok(id) = Uuid::parse_str(n.payload()) {
                        return Ok(News::Progress(id));
                    }
                }
                _ => {}
            }
        }
    }
}
