//! `GET /v1/jobs/{id}/stream` (service-api.md "The stream").
//!
//! Protocol, server to client:
//! 1. `{"type":"state","job":{...}}` with the job as it is now;
//! 2. per frame, `{"type":"frame","iteration":k,"progress":{...},"layers":[...],"width":w,
//!    "height":h,"image_width":W,"image_height":H}` then one binary message: the PNG of
//!    that frame's image, `w × h` pixels. That is the image's size `W × H` but for a
//!    large image's preview, sent smaller (`live::PREVIEW_SIDE`) for the client to scale
//!    up: the first picture is on the client sooner;
//! 3. `{"type":"done","job":{...}}` (succeeded or cancelled) or
//!    `{"type":"error","error":{...},"job":{...}}` (failed), then the server closes.
//!
//! Each connection reads the job's `watch` channel: it holds only the newest snapshot, so
//! a slow client skips frames instead of making the server buffer them; a late joiner
//! starts from the newest frame. A finished job (no longer live) is served from the
//! store: state, the stored final frame, done.
//!
//! Memory per watcher is bounded, whatever the image size: a frame's PNG is shared by
//! every watcher (one `Bytes`), and goes out as a binary message in fragments of
//! [`FRAGMENT`] bytes (RFC 6455 §5.4). The WebSocket library copies each frame it sends
//! into the connection's write buffer, so one unfragmented 4096² PNG (tens of MB) per
//! watcher that does not read was a copy per watcher (measured: 256 such watchers held
//! +5.2 GB). A watcher holds no reference to a job's frames while it waits for its
//! client; a client that stops reading is cut by the connection's stall limit
//! (`service::stall`). That is why the upgrade is done here with tokio-tungstenite
//! rather than through axum's `WebSocketUpgrade`, whose messages cannot be fragmented.

use super::error::{ApiError, ErrorCode, ErrorDetail};
use super::extract::JobId;
use super::jobs::{LiveFrame, Snapshot, StoredFrame, Watch};
use super::metrics::WatcherGuard;
use super::state::AppState;
use super::store::{JobError, JobRecord, JobState, Layer, Progress};
use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::Response;
use bytes::Bytes;
use futures_util::stream::SplitSink;
use futures_util::{SinkExt, StreamExt};
use hyper_util::rt::TokioIo;
use serde::Serialize;
use std::sync::{Arc, Weak};
use tokio_tungstenite::tungstenite::protocol::frame::coding::{CloseCode, Data, OpCode};
use tokio_tungstenite::tungstenite::protocol::frame::Frame;
use tokio_tungstenite::tungstenite::protocol::{CloseFrame, Role, WebSocketConfig};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::WebSocketStream;
use uuid::Uuid;

/// Largest message (and frame) a client may send on a stream. Clients only need control
/// frames (ping, close: ≤ 125 bytes) and whatever they send is read and dropped; a
/// larger message ends that stream (without a bound, 256 watchers could make the server
/// buffer gigabytes).
pub const MAX_CLIENT_MESSAGE: usize = 64 * 1024;

/// Size of the fragments a frame's PNG is sent in: the most a watcher's write buffer
/// holds of it.
pub const FRAGMENT: usize = 16 * 1024;

type Ws = WebSocketStream<TokioIo<hyper::upgrade::Upgraded>>;
type Tx = SplitSink<Ws, Message>;

/// The upgrade request's `Sec-WebSocket-Key`, or why this is not a WebSocket request
/// (RFC 6455 §4.2.1).
fn websocket_key(headers: &HeaderMap) -> Result<String, &'static str> {
    let has_token = |name: header::HeaderName, token: &str| {
        headers.get_all(name).iter().any(|v| {
            v.to_str()
                .is_ok_and(|v| v.split(',').any(|t| t.trim().eq_ignore_ascii_case(token)))
        })
    };
    if !has_token(header::CONNECTION, "upgrade") {
        return Err("`Connection: upgrade` is missing");
    }
    if !has_token(header::UPGRADE, "websocket") {
        return Err("`Upgrade: websocket` is missing");
    }
    if headers
        .get(header::SEC_WEBSOCKET_VERSION)
        .is_none_or(|v| v.as_bytes() != b"13")
    {
        return Err("`Sec-WebSocket-Version: 13` is missing");
    }
    headers
        .get(header::SEC_WEBSOCKET_KEY)
        .and_then(|v| v.to_str().ok())
        .map(str::to_owned)
        .ok_or("`Sec-WebSocket-Key` is missing")
}

pub async fn stream(
    State(st): State<AppState>,
    JobId(id): JobId,
    mut req: Request,
) -> Result<Response, ApiError> {
    if st.jobs.get(id).await?.is_none() {
        return Err(ApiError::not_found_job(&id.to_string()));
    }
    let not_ws = |why: &str| {
        ApiError::new(
            ErrorCode::InvalidParameter,
            format!("this route is a WebSocket: {why}"),
        )
    };
    let key = websocket_key(req.headers()).map_err(not_ws)?;
    let on_upgrade = req
        .extensions_mut()
        .remove::<hyper::upgrade::OnUpgrade>()
        .ok_or_else(|| not_ws("this connection cannot be upgraded"))?;
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
    let guard = WatcherGuard::new(Arc::clone(&st.metrics));
    tokio::spawn(async move {
        let _guard = guard;
        match on_upgrade.await {
            Ok(upgraded) => watch(upgraded, st, id).await,
            Err(e) => tracing::debug!(%id, "stream upgrade failed: {e}"),
        }
    });
    let accept = tokio_tungstenite::tungstenite::handshake::derive_accept_key(key.as_bytes());
    Response::builder()
        .status(StatusCode::SWITCHING_PROTOCOLS)
        .header(header::CONNECTION, "upgrade")
        .header(header::UPGRADE, "websocket")
        .header(header::SEC_WEBSOCKET_ACCEPT, accept)
        .body(axum::body::Body::empty())
        .map_err(|e| ApiError::internal("answering a stream's upgrade", &e))
}

/// One watcher's connection, from the upgrade to the close.
async fn watch(upgraded: hyper::upgrade::Upgraded, st: AppState, id: Uuid) {
    // Small buffers: 256 watchers × the library's default 128 KiB to read and 128 KiB to
    // write would be 64 MiB before any frame. Writes go out frame by frame.
    let config = WebSocketConfig::default()
        .read_buffer_size(4096)
        .write_buffer_size(0)
        .max_message_size(Some(MAX_CLIENT_MESSAGE))
        .max_frame_size(Some(MAX_CLIENT_MESSAGE));
    let socket = Ws::from_raw_socket(TokioIo::new(upgraded), Role::Server, Some(config)).await;
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
                code: CloseCode::Away,
                reason: "server shutting down".into(),
            }))).await;
        }
    }
    let _ = tx.close().await;
    reader.abort();
}

#[derive(Debug, thiserror::Error)]
enum StreamError {
    #[error("send: {0}")]
    Send(#[from] tokio_tungstenite::tungstenite::Error),
    #[error("{0}")]
    Other(String),
}

/// A stream's text messages (service-api.md, the stream): one JSON object each, named by
/// its `type`.
#[derive(Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
enum StreamMessage<'a> {
    /// The job as it is now.
    State { job: &'a JobRecord },
    /// A frame's header; its PNG follows as a binary message.
    Frame {
        iteration: u32,
        /// Live frames only: a preview before the first iteration.
        #[serde(skip_serializing_if = "Option::is_none")]
        preview: Option<bool>,
        progress: Option<&'a Progress>,
        layers: &'a [Layer],
        #[serde(flatten)]
        size: FrameSize,
    },
    /// The job succeeded or was cancelled: the last message.
    Done { job: &'a JobRecord },
    /// The job failed (with the job) or cannot be streamed (without).
    Error {
        error: ErrorDetail,
        #[serde(skip_serializing_if = "Option::is_none")]
        job: Option<&'a JobRecord>,
    },
}

/// The size of the PNG a frame message announces, and of the image it stands for.
#[derive(Serialize)]
struct FrameSize {
    width: u32,
    height: u32,
    image_width: u32,
    image_height: u32,
}

impl FrameSize {
    /// A PNG that is the image at full size.
    fn full((width, height): (u32, u32)) -> Self {
        Self {
            width,
            height,
            image_width: width,
            image_height: height,
        }
    }
}

async fn send_json(tx: &mut Tx, m: &StreamMessage<'_>) -> Result<(), StreamError> {
    send_text(tx, to_text(m)?).await
}

fn to_text(m: &StreamMessage<'_>) -> Result<String, StreamError> {
    serde_json::to_string(m).map_err(other)
}

async fn send_text(tx: &mut Tx, text: String) -> Result<(), StreamError> {
    tx.send(Message::Text(text.into())).await?;
    Ok(())
}

/// One binary message in fragments of [`FRAGMENT`] bytes, each a slice of `data` (no
/// copy until the library frames it).
async fn send_binary(tx: &mut Tx, data: Bytes) -> Result<(), StreamError> {
    let n = data.len().div_ceil(FRAGMENT).max(1);
    for k in 0..n {
        let part = data.slice((k * FRAGMENT).min(data.len())..((k + 1) * FRAGMENT).min(data.len()));
        let opcode = if k == 0 {
            OpCode::Data(Data::Binary)
        } else {
            OpCode::Data(Data::Continue)
        };
        tx.send(Message::Frame(Frame::message(part, opcode, k + 1 == n)))
            .await?;
    }
    Ok(())
}

/// A frame's header message and PNG. Only the PNG's bytes are held while the client
/// takes them, not the frame (whose buffers are ~240 bytes a pixel).
async fn send_frame(tx: &mut Tx, lf: Arc<LiveFrame>) -> Result<(), StreamError> {
    let shown = lf.stream_png().await.map_err(StreamError::Other)?;
    let header = to_text(&StreamMessage::Frame {
        iteration: lf.iteration,
        preview: Some(lf.preview),
        progress: Some(&lf.progress),
        layers: &lf.layers,
        size: FrameSize {
            width: shown.width,
            height: shown.height,
            image_width: lf.width,
            image_height: lf.height,
        },
    })?;
    drop(lf);
    send_text(tx, header).await?;
    send_binary(tx, shown.png).await
}

/// The last message for a finished job.
fn final_message(job: &JobRecord) -> StreamMessage<'_> {
    if job.state == JobState::Failed {
        let error = job
            .error
            .clone()
            .unwrap_or_else(|| JobError::new(ErrorCode::RenderFailed, "the render failed"));
        StreamMessage::Error {
            error: ApiError::new(error.code, error.message).detail(),
            job: Some(job),
        }
    } else {
        StreamMessage::Done { job }
    }
}

async fn serve(tx: &mut Tx, st: &AppState, id: Uuid) -> Result<(), StreamError> {
    let watch = match st.jobs.watch(id).await {
        Ok(w) => w,
        // The store cannot serve it (unreachable, or the job's files are gone): the
        // stream says why, in the error shape of every other answer.
        Err(e) => {
            let error = ApiError::from(e).detail();
            return send_json(tx, &StreamMessage::Error { error, job: None }).await;
        }
    };
    let (job, frame) = match watch {
        Watch::Live(wrx) => return follow(tx, st, id, wrx).await,
        Watch::Stored(job, frame) => (job, frame),
        Watch::NotFound => {
            // Unknown after a race with DELETE.
            let e = ApiError::not_found_job(&id.to_string());
            let error = e.detail();
            return send_json(tx, &StreamMessage::Error { error, job: None }).await;
        }
    };
    send_json(tx, &StreamMessage::State { job: &job }).await?;
    if let Some(frame) = frame {
        send_stored_frame(tx, &job, frame).await?;
    }
    if job.state.is_finished() {
        send_json(tx, &final_message(&job)).await?;
    }
    Ok(())
}

fn other(e: impl std::fmt::Display) -> StreamError {
    StreamError::Other(e.to_string())
}

/// Times a stream follows its job to another attempt (a lost lease, a released job)
/// before it stops with the job's state: more than its attempts allow, a bound only
/// against a channel that keeps closing.
const MAX_FOLLOWS: u32 = 16;

/// A live job's snapshots, newest first, until it finishes. If its channel closes first
/// (the job left this node's worker), it follows the job wherever it runs next
/// (`Jobs::watch_again`), saying so with a `state` message; else it ends with the
/// job's state.
async fn follow(
    tx: &mut Tx,
    st: &AppState,
    id: Uuid,
    mut wrx: tokio::sync::watch::Receiver<Arc<Snapshot>>,
) -> Result<(), StreamError> {
    let snap: Arc<Snapshot> = wrx.borrow_and_update().clone();
    send_json(tx, &StreamMessage::State { job: &snap.job }).await?;
    drop(snap);
    // The frame last sent, by identity only: holding it would keep its buffers alive
    // while this client is slow.
    let mut sent: Weak<LiveFrame> = Weak::new();
    for _ in 0..MAX_FOLLOWS {
        if follow_channel(tx, &mut wrx, &mut sent).await? {
            return Ok(());
        }
        match st.jobs.watch_again(id).await.map_err(other)? {
            Some(Watch::Live(next)) => {
                wrx = next;
                let job = wrx.borrow().job.clone();
                send_json(tx, &StreamMessage::State { job: &job }).await?;
            }
            Some(Watch::Stored(job, frame)) => {
                if let Some(frame) = frame {
                    send_stored_frame(tx, &job, frame).await?;
                }
                return send_json(tx, &final_message(&job)).await;
            }
            Some(Watch::NotFound) | None => break,
        }
    }
    if let Some(job) = st.jobs.get(id).await.map_err(other)? {
        if job.state.is_finished() {
            send_json(tx, &final_message(&job)).await?;
        } else {
            send_json(tx, &StreamMessage::State { job: &job }).await?;
        }
    }
    Ok(())
}

/// Sends one channel's snapshots (each new frame, then `done` or `error` when the job
/// finishes): true once finished, false if the channel closed first (requeued on
/// shutdown, the lease lost, or deleted).
async fn follow_channel(
    tx: &mut Tx,
    wrx: &mut tokio::sync::watch::Receiver<Arc<Snapshot>>,
    sent: &mut Weak<LiveFrame>,
) -> Result<bool, StreamError> {
    loop {
        let s = wrx.borrow_and_update().clone();
        // Serialised now, so the snapshot (and its frame) is not held while the client
        // reads.
        let finished = match s.job.state.is_finished() {
            true => Some(to_text(&final_message(&s.job))?),
            false => None,
        };
        let fresh = s
            .frame
            .clone()
            .filter(|f| !Weak::ptr_eq(sent, &Arc::downgrade(f)));
        drop(s);
        if let Some(f) = fresh {
            *sent = Arc::downgrade(&f);
            send_frame(tx, f).await?;
        }
        if let Some(done) = finished {
            send_text(tx, done).await?;
            return Ok(true);
        }
        if wrx.changed().await.is_err() {
            return Ok(false);
        }
    }
}

/// The stored final frame of a finished job, read from its file fragment by fragment
/// (never the whole file in memory per watcher). Nothing if the file is gone.
async fn send_stored_frame(
    tx: &mut Tx,
    job: &JobRecord,
    frame: StoredFrame,
) -> Result<(), StreamError> {
    use tokio::io::AsyncReadExt;
    let Ok(mut file) = tokio::fs::File::open(&frame.image).await else {
        return Ok(());
    };
    let len = file.metadata().await.map(|m| m.len()).unwrap_or(0);
    // Fragments of exactly the length the file had: a message's size is fixed once its
    // first fragment is out. The first is read before the header, which gives the size
    // its PNG header declares.
    let mut left = len;
    let mut first = true;
    loop {
        let want = usize::try_from(left.min(FRAGMENT as u64)).unwrap_or(FRAGMENT);
        let mut buf = vec![0u8; want];
        file.read_exact(&mut buf)
            .await
            .map_err(|e| StreamError::Other(format!("reading the stored frame: {e}")))?;
        left -= want as u64;
        let opcode = if first {
            send_stored_header(tx, job, &frame, &buf).await?;
            OpCode::Data(Data::Binary)
        } else {
            OpCode::Data(Data::Continue)
        };
        first = false;
        tx.send(Message::Frame(Frame::message(buf, opcode, left == 0)))
            .await?;
        if left == 0 {
            return Ok(());
        }
    }
}

/// The `frame` message of a stored final frame whose PNG starts with `head`.
async fn send_stored_header(
    tx: &mut Tx,
    job: &JobRecord,
    frame: &StoredFrame,
    head: &[u8],
) -> Result<(), StreamError> {
    let size = crate::raster::png_size(head).unwrap_or_default();
    let message = StreamMessage::Frame {
        iteration: job.progress.as_ref().map_or(0, |p| p.iteration),
        preview: None,
        progress: job.progress.as_ref(),
        layers: &frame.layers,
        size: FrameSize::full(size),
    };
    send_json(tx, &message).await
}
