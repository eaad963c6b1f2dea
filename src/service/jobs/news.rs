//! What this node hears from the others through the store (`store::News`, PostgreSQL's
//! `LISTEN`/`NOTIFY`): a queued job wakes the idle workers at once instead of at their
//! next poll, a relayed frame its relays. The polls stay (notifications sent while the
//! connection is down are lost); this only shortens them.

use super::Inner;
use crate::service::store::News;
use std::sync::Arc;
use std::time::Duration;

/// Pause before listening again after the database went away.
const RETRY: Duration = Duration::from_secs(1);

/// Listens until the node stops (nothing on the embedded store).
pub(super) async fn listen(inner: Arc<Inner>) {
    loop {
        let listener = tokio::select! {
            l = inner.store.listen() => l,
            () = inner.stop.cancelled() => return,
        };
        let mut listener = match listener {
            Ok(Some(l)) => l,
            Ok(None) => return,
            Err(e) => {
                tracing::debug!("LISTEN: {e}");
                tokio::select! {
                    () = tokio::time::sleep(RETRY) => continue,
                    () = inner.stop.cancelled() => return,
                }
            }
        };
        loop {
            let news = tokio::select! {
                n = listener.next() => n,
                () = inner.stop.cancelled() => return,
            };
            match news {
                Ok(News::Queued) => inner.wake_workers(),
                Ok(News::Progress(id)) => {
                    // No receiver (no relay on this node) is not an error.
                    let _ = inner.progressed.send(id);
                }
                Err(e) => {
                    tracing::debug!("LISTEN: {e}");
                    tokio::select! {
                        () = tokio::time::sleep(RETRY) => {}
                        () = inner.stop.cancelled() => return,
                    }
                }
            }
        }
    }
}
