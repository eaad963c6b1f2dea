//! The REST surface of service-api.md as one router: its routes, its limit layers
//! (body size, request deadline, origin, token) and the JSON error mapper outermost.
//! Handlers live in [`super::handlers`], [`super::ws`] and [`super::examples`]; what they
//! share in [`super::state`], [`super::error`] and [`super::extract`].

use super::error::json_errors;
pub use super::error::{ApiError, ErrorBody, ErrorCode, ErrorDetail};
pub use super::extract::{JobId, Json, Params, SceneBody, SceneContent};
pub use super::handlers::MAX_NAME_CHARS;
use super::handlers::*;
pub use super::state::AppState;
use super::{auth, examples, ws};
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;

/// The whole application; `run` serves it, tests may call it directly.
pub fn router(state: AppState) -> Router {
    let v1 = Router::new()
        .route("/jobs", post(create_job).get(list_jobs))
        .route("/jobs/{id}", get(get_job).delete(delete_job))
        .route("/jobs/{id}/scene", get(get_scene))
        .route("/jobs/{id}/cancel", post(cancel_job))
        .route("/jobs/{id}/frame", get(get_frame))
        .route("/jobs/{id}/iterations", get(get_iterations))
        .route("/jobs/{id}/stream", get(ws::stream))
        .route("/examples", get(examples::list))
        // Unknown `/v1` routes too are behind the token (401, not 404: no route map for
        // strangers).
        .fallback(not_found)
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::require_token,
        ));
    let max_body = state.max_body_bytes;
    Router::new()
        .route("/", get(viewer))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .nest("/v1", v1)
        .fallback(not_found)
        // Limits in one place: a declared Content-Length over the limit is refused before
        // any handler (`refuse_oversized`); axum's own limit covers chunked bodies; then
        // the error mapper
        // outermost so even layer-made responses leave as JSON.
        .layer(axum::extract::DefaultBodyLimit::max(max_body))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            refuse_oversized,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            request_deadline,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::check_origin,
        ))
        .layer(axum::middleware::map_response_with_state(
            state.clone(),
            json_errors,
        ))
        .with_state(state)
}

/// A worker node's own HTTP (`glimpse worker --metrics-addr`): `/healthz` and
/// `/metrics` as an API node answers them (the same handlers, `Host`/`Origin` checks and
/// error shape), nothing else.
pub fn node_router(state: AppState) -> Router {
    Router::new()
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .fallback(not_found)
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::check_origin,
        ))
        .layer(axum::middleware::map_response_with_state(
            state.clone(),
            json_errors,
        ))
        .with_state(state)
}

/// The whole of a request, body included, must arrive and be answered within this time
/// (the header has its own timeout, `service::HEADER_TIMEOUT`). Without it a client
/// sending one byte a minute holds a connection and a task for good, and enough of them
/// exhaust the server's file descriptors. 60 s carries the 8 MiB body limit (67 Mbit) at
/// 1.1 Mbit/s.
/// A stream's handler ends when it answers the upgrade, so streams are not cut.
pub const REQUEST_DEADLINE: std::time::Duration = std::time::Duration::from_secs(60);

/// Answers `408 request_timeout` (and closes the connection: its body is unread) when the
/// request is not done within `AppState::request_deadline`.
async fn request_deadline(
    State(st): State<AppState>,
    req: Request,
    next: axum::middleware::Next,
) -> Response {
    match tokio::time::timeout(st.request_deadline, next.run(req)).await {
        Ok(res) => res,
        Err(_) => {
            let mut res = ApiError::new(
                ErrorCode::RequestTimeout,
                format!(
                    "the request was not complete within {} s",
                    st.request_deadline.as_secs_f64()
                ),
            )
            .into_response();
            res.headers_mut()
                .insert(header::CONNECTION, HeaderValue::from_static("close"));
            res
        }
    }
}

/// How much of a declared-oversized body is read and discarded before answering 413.
const DRAIN_CAP_BYTES: u64 = 64 << 20;

/// How long that draining may take (a slow client must not hold the task).
const DRAIN_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(5);

/// Refuses a body whose `Content-Length` exceeds the limit, before any handler runs.
///
/// Answering at once and closing while the client is still writing makes the client's
/// write fail (broken pipe) before it can read the 413 — the error it gets is then a
/// transport error, not ours. So the rest of the body is read and discarded (bounded in
/// bytes and time), then the 413 goes out with `Connection: close`, since the connection
/// is not reusable. Chunked bodies are bounded by axum's `DefaultBodyLimit` while read.
async fn refuse_oversized(
    State(st): State<AppState>,
    req: Request,
    next: axum::middleware::Next,
) -> Response {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    let Some(len) = declared.filter(|&n| n > st.max_body_bytes as u64) else {
        return next.run(req).await;
    };
    if len <= DRAIN_CAP_BYTES {
        let mut body = req.into_body().into_data_stream();
        let drain = async {
            use futures_util::StreamExt;
            while let Some(Ok(_)) = body.next().await {}
        };
        let _ = tokio::time::timeout(DRAIN_TIMEOUT, drain).await;
    }
    let mut res = ApiError::new(
        ErrorCode::TooLarge,
        format!(
            "the request body ({len} bytes) is larger than the limit of {} bytes",
            st.max_body_bytes
        ),
    )
    .into_response();
    res.headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
    res
}
