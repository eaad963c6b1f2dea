//! `GET /v1/jobs/{id}/stream` (service-api.md "The stream").
//!
//! Protocol, server to client:
//! 1. `{"type":"state","job":{...}}` with the job as it is now;
//! 2. per frame, `{"type":"frame","iteration":k,"progress":{...},"layers":[...]}` then one
//!    binary message: the PNG of that frame's image;
//! 3. `{"type":"done","job":{...}}` (succeeded or cancelled) or
//!    `{"type":"error","error":{...},"job":{...}}` (failed), then the server closes.
//!
//! Each connection reads the job's `watch` channel: it holds only the newest snapshot, so
//! a slow client skips frames instead of making the server buffer them; a late joiner
//! starts from the newest frame. A finished job (no longer live) is served from the
//! store: state, the stored final frame, done.

use super::http::{ApiError, AppState, ErrorCode, JobId};
use super::jobs::{LiveFrame, Snapshot};
use super::metrics::WatcherGuard;
use super::store::{JobRecord, JobState};
use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::response::Response;
use futures_util::stream::SplitSink;
use futures_util::{SinkExt, StreamExt};
use serde_json::{json, Value};
use std::sync::Arc;
use std::time::Duration;
use uuid::Uuid;

/// A client that does not take a message within this time is dropped (it would otherwise
/// hold a connection and a frame alive forever).
const SEND_TIMEOUT: Duration = Duration::from_secs(30);

/// Largest message (and frame) a client may send on a stream. Clients only need control
/// frames (ping, close: ≤ 125 bytes) and whatever they send is read and dropped, but axum's
/// default would buffer up to 64 MiB per message: 256 watchers could make the server hold
/// 16 GiB. A larger message ends that stream.
pub const MAX_CLIENT_MESSAGE: usize = 64 * 1024;

pub async fn stream(
    State(st): State<AppState>,
    JobId(id): JobId,
    ws: Result<WebSocketUpgrade, axum::extract::ws::rejection::WebSocketUpgradeRejection>,
) -> Result<Response, ApiError> {
    if st.jobs.get(id).await?.is_none() {
        return Err(ApiError::not_found_job(&id.to_string()));
    }
    let ws = ws.map_err(|e| {
        ApiError::new(
            ErrorCode::InvalidParameter,
            format!("this route is a WebSocket: {}", e.body_text()),
        )
    })?;
    let watching = st
        .metrics
        .ws_watchers
        .load(std::sync::atomic::Ordering::Relaxed);
    if usize::try_from(watching).unwrap_or(0) >= st.max_watchers {
        let mut e = ApiError::new(
            ErrorCode::Unavailable,
            format!("too many open streams ({watching}); retry later"),
        );
        e.retry_after_s = Some(5);
        return Err(e);
    }
    let ws = ws
        .max_message_size(MAX_CLIENT_MESSAGE)
        .max_frame_size(MAX_CLIENT_MESSAGE);
    Ok(ws.on_upgrade(move |socket| async move {
        let _guard = WatcherGuard::new(&st.metrics);
        let (mut tx, mut rx) = socket.split();
        // Read (and ignore) what the client sends, so pings are answered and a close is
        // noticed; its end tells the writer to stop.
        let closed = tokio_util::sync::CancellationToken::new();
        let closed2 = closed.clone();
        let reader = tokio::spawn(async move {
            while let Some(Ok(m)) = rx.next().await {
                if matches!(m, Message::Close(_)) {
                    break;
                }
            }
            closed2.cancel();
        });
        tokio::select! {
            r = serve(&mut tx, &st, id) => {
                if let Err(e) = r {
                    tracing::debug!(%id, "stream ended: {e}");
                }
            }
            () = closed.cancelled() => {}
            () = st.stop.cancelled() => {
                let _ = tx.send(Message::Close(Some(CloseFrame {
                    code: axum::extract::ws::close_code::AWAY,
                    reason: "server shutting down".into(),
                }))).await;
            }
        }
        let _ = tx.close().await;
        reader.abort();
    }))
}

type Tx = SplitSink<WebSocket, Message>;

#[derive(Debug, thiserror::Error)]
enum StreamError {
    #[error("send: {0}")]
    Send(#[from] axum::Error),
    #[error("client too slow")]
    Timeout,
    #[error("{0}")]
    Other(String),
}

async fn send(tx: &mut Tx, m: Message) -> Result<(), StreamError> {
    tokio::time::timeout(SEND_TIMEOUT, tx.send(m))
        .await
        .map_err(|_| StreamError::Timeout)??;
    Ok(())
}

async fn send_json(tx: &mut Tx, v: &Value) -> Result<(), StreamError> {
    send(tx, Message::Text(v.to_string().into())).await
}

async fn send_frame(tx: &mut Tx, lf: &Arc<LiveFrame>) -> Result<(), StreamError> {
    let png = lf.image_png().await.map_err(StreamError::Other)?;
    send_json(
        tx,
        &json!({"type": "frame", "iteration": lf.frame.iteration, "progress": lf.progress, "layers": lf.layers}),
    )
    .await?;
    send(tx, Message::Binary(png)).await
}

/// The last message for a finished job.
fn final_message(job: &JobRecord) -> Value {
    if job.state == JobState::Failed {
        let error = job
            .error
            .clone()
            .unwrap_or_else(|| json!({"code": "render_failed", "message": "the render failed"}));
        let error = json!({
            "code": error.get("code").cloned().unwrap_or(json!("render_failed")),
            "message": error.get("message").cloned().unwrap_or(json!("the render failed")),
            "path": "",
        });
        json!({"type": "error", "error": error, "job": job})
    } else {
        json!({"type": "done", "job": job})
    }
}

async fn serve(tx: &mut Tx, st: &AppState, id: Uuid) -> Result<(), StreamError> {
    if let Some(live) = st.jobs.live(id) {
        let mut wrx = live.tx.subscribe();
        drop(live); // do not keep the job alive; the receiver is enough
        let mut snap: Arc<Snapshot> = wrx.borrow_and_update().clone();
        send_json(tx, &json!({"type": "state", "job": snap.job})).await?;
        let mut sent: Option<Arc<LiveFrame>> = None;
        loop {
            if let Some(f) = &snap.frame {
                if !sent.as_ref().is_some_and(|s| Arc::ptr_eq(s, f)) {
                    send_frame(tx, f).await?;
                    sent = Some(Arc::clone(f));
                }
            }
            if snap.job.state.is_finished() {
                send_json(tx, &final_message(&snap.job)).await?;
                return Ok(());
            }
            if wrx.changed().await.is_err() {
                // The job left the live set without a final snapshot (requeued on
                // shutdown, or deleted): say where it stands and stop.
                break;
            }
            snap = wrx.borrow_and_update().clone();
        }
        if let Some(job) = st
            .jobs
            .store()
            .get(id)
            .await
            .map_err(|e| StreamError::Other(e.to_string()))?
        {
            if job.state.is_finished() {
                send_json(tx, &final_message(&job)).await?;
            } else {
                send_json(tx, &json!({"type": "state", "job": job})).await?;
            }
        }
        return Ok(());
    }
    // Not live: finished (or unknown after a race with DELETE).
    let Some(job) = st
        .jobs
        .store()
        .get(id)
        .await
        .map_err(|e| StreamError::Other(e.to_string()))?
    else {
        let e = ApiError::not_found_job(&id.to_string());
        return send_json(tx, &json!({"type": "error", "error": e.body()["error"]})).await;
    };
    send_json(tx, &json!({"type": "state", "job": job})).await?;
    if job.has_frame {
        if let Some(path) = st.jobs.store().layer_path(id, "image", false) {
            if let Ok(png) = tokio::fs::read(&path).await {
                let iteration = job
                    .progress
                    .as_ref()
                    .and_then(|p| p.get("iteration"))
                    .cloned()
                    .unwrap_or(json!(0));
                let layers: Vec<&str> = super::store::LAYER_FILES
                    .iter()
                    .copied()
                    .filter(|l| {
                        st.jobs
                            .store()
                            .layer_path(id, l, false)
                            .is_some_and(|p| p.exists())
                    })
                    .collect();
                send_json(
                    tx,
                    &json!({"type": "frame", "iteration": iteration, "progress": job.progress, "layers": layers}),
                )
                .await?;
                send(tx, Message::Binary(png.into())).await?;
            }
        }
    }
    if job.state.is_finished() {
        send_json(tx, &final_message(&job)).await?;
    }
    Ok(())
}
