//! The REST surface of service-api.md: the router, its limit layers, our extractors and
//! [`ApiError`], the only type that knows HTTP status codes.
//!
//! Every error leaves as `{"error": {"code", "message", "path"}}`: our handlers return
//! [`ApiError`]; our extractors ([`Json`], [`JobId`], [`Params`], [`SceneBody`]) map
//! axum's rejections to it; and [`json_errors`] rewrites whatever else axum or tower-http
//! produce on their own (unknown route, wrong method, body over the limit) into the
//! same shape, so a client never has to parse plain text.

use super::jobs::{CancelOutcome, DeleteOutcome, FrameBytes, FrameLookup, Jobs, SubmitError};
use super::metrics::Metrics;
use super::store::{clip, Failure, JobRecord, JobState, Layer, StoreError};
use super::{auth, examples, ws};
use crate::scene::{parse_scene, Problem, RenderMode, SceneErrorKind, SceneOrigin};
use axum::extract::{FromRequest, FromRequestParts, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use bytes::Bytes;
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use tokio_util::sync::CancellationToken;
use uuid::Uuid;

/// Shared by every handler.
#[derive(Clone)]
pub struct AppState {
    pub jobs: Jobs,
    pub metrics: Arc<Metrics>,
    /// Bearer token for `/v1` (None: open).
    pub token: Option<Arc<str>>,
    /// Fires on shutdown: open streams close.
    pub stop: CancellationToken,
    pub max_body_bytes: usize,
    /// [`REQUEST_DEADLINE`] unless a test shortens it.
    pub request_deadline: std::time::Duration,
    pub max_watchers: usize,
    /// Which `Host` and `Origin` name this server (checked only without a token).
    pub origin: Arc<auth::OriginPolicy>,
    /// Bytes of request bodies in validation, in KiB permits (`Config::validation_budget`),
    /// and the budget's size.
    pub uploads: Arc<tokio::sync::Semaphore>,
    pub upload_budget_kib: usize,
}

// ---------------------------------------------------------------------------------------
// Errors

pub use super::error_code::ErrorCode;

/// An error response. Internal causes are logged, not shown (the message stays generic).
#[derive(Debug)]
pub struct ApiError {
    pub code: ErrorCode,
    pub message: String,
    /// JSON path of the field at fault (scene errors), or the query parameter; "" if none.
    pub path: String,
    /// Further problems of a refused scene (the first is `message`/`path`).
    pub problems: Vec<crate::scene::Problem>,
    pub retry_after_s: Option<u32>,
}

impl ApiError {
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        Self {
            code,
            message: message.into(),
            path: String::new(),
            problems: Vec::new(),
            retry_after_s: None,
        }
    }

    #[must_use]
    pub fn at(mut self, path: impl Into<String>) -> Self {
        self.path = path.into();
        self
    }

    pub fn not_found_job(id: &str) -> Self {
        Self::new(
            ErrorCode::NotFound,
            format!("no job with id {:?}", clip(id)),
        )
    }

    /// 503 with `Retry-After`: the server cannot take this now but will later.
    pub fn unavailable(message: impl Into<String>, retry_after_s: u32) -> Self {
        let mut e = Self::new(ErrorCode::Unavailable, message);
        e.retry_after_s = Some(retry_after_s);
        e
    }

    pub fn internal(context: &str, e: &dyn std::fmt::Display) -> Self {
        tracing::error!("{context}: {e}");
        Self::new(
            ErrorCode::Internal,
            format!("internal error while {context}; see the server log"),
        )
    }

    /// The JSON body, also used for stream `error` messages.
    #[must_use]
    pub fn body(&self) -> ErrorBody {
        ErrorBody {
            error: self.detail(),
        }
    }

    /// What the body's `error` holds.
    #[must_use]
    pub fn detail(&self) -> ErrorDetail {
        ErrorDetail {
            code: self.code,
            message: self.message.clone(),
            path: self.path.clone(),
            problems: if self.problems.len() > 1 {
                self.problems.clone()
            } else {
                Vec::new()
            },
        }
    }
}

/// Every error answer's body: `{"error": {"code", "message", "path"}}` (service-api.md).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

/// An error as clients read it; `problems` lists every problem of a refused scene when
/// there are several (the first is `message`/`path`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ErrorDetail {
    pub code: ErrorCode,
    pub message: String,
    pub path: String,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub problems: Vec<crate::scene::Problem>,
}

impl From<StoreError> for ApiError {
    /// A store that cannot be reached or written is a fault that passes: 503 with
    /// `Retry-After`, saying which it is (an unreachable database, `database_unreachable`,
    /// or a disk that refuses a write, `unavailable`). A corrupt record is a 500.
    fn from(e: StoreError) -> Self {
        let message = match e.failure() {
            Failure::Corrupt => return Self::internal("reading the job store", &e),
            Failure::Unreachable => {
                tracing::error!("job database unreachable: {e}");
                let mut err = Self::unavailable(
                    format!("the job database cannot be reached ({e}); retry later"),
                    UNREACHABLE_RETRY_AFTER_S,
                );
                err.code = ErrorCode::DatabaseUnreachable;
                return err;
            }
            Failure::FilesMissing => {
                // The server's own path stays in its log (`Store::check_files`).
                let id = match &e {
                    StoreError::FilesMissing(id, _) => id.to_string(),
                    _ => String::new(),
                };
                return Self::new(
                    ErrorCode::FilesMissing,
                    format!("the stored images of job {id} are missing on the server (removed outside it); its record is kept, but no frame can be served: DELETE the job and submit its scene again"),
                );
            }
            Failure::Full => "the job store's disk is full or read-only; retry later",
            Failure::Other => "the job store failed to read or write just now; retry later",
        };
        tracing::error!("job store: {e}");
        Self::unavailable(message, STORE_RETRY_AFTER_S)
    }
}

/// `Retry-After` when the store fails: an operator has to free space, which takes a while.
const STORE_RETRY_AFTER_S: u32 = 30;
/// `Retry-After` when the database cannot be reached: a restart or a failover takes
/// seconds, and nothing is lost by asking again soon.
const UNREACHABLE_RETRY_AFTER_S: u32 = 5;

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let mut res = (self.code.status(), axum::Json(self.body())).into_response();
        if let Some(s) = self.retry_after_s {
            res.headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(s));
        }
        res
    }
}

/// Rewrites error responses that did not come from [`ApiError`] (axum's 404/405, the body
/// limit layer's 413, WebSocket upgrade refusals) into our JSON shape.
pub async fn json_errors(State(st): State<AppState>, res: Response) -> Response {
    let status = res.status();
    if !(status.is_client_error() || status.is_server_error()) {
        return res;
    }
    st.metrics.http_errors.fetch_add(1, Ordering::Relaxed);
    let is_json = res
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if is_json {
        return res;
    }
    let (code, message) = match status {
        StatusCode::NOT_FOUND => (ErrorCode::NotFound, "no such route".to_owned()),
        StatusCode::METHOD_NOT_ALLOWED => (
            ErrorCode::MethodNotAllowed,
            "this method is not allowed on this route".to_owned(),
        ),
        StatusCode::PAYLOAD_TOO_LARGE => (
            ErrorCode::TooLarge,
            format!(
                "the request body is larger than the limit of {} bytes",
                st.max_body_bytes
            ),
        ),
        s if s.is_server_error() => (
            ErrorCode::Internal,
            "internal error; see the server log".to_owned(),
        ),
        s => (
            ErrorCode::InvalidParameter,
            format!(
                "bad request ({})",
                s.canonical_reason().unwrap_or("client error")
            ),
        ),
    };
    let (mut parts, _) = res.into_parts();
    parts.headers.remove(header::CONTENT_LENGTH);
    parts.headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    let body = serde_json::to_string(&ApiError::new(code, message).body())
        .unwrap_or_else(|_| String::from("{}"));
    Response::from_parts(parts, axum::body::Body::from(body))
}

// ---------------------------------------------------------------------------------------
// Extractors

/// `Json<T>` with our rejection: unreadable JSON is `400 invalid_json` with the path where
/// deserialisation failed (serde_path_to_error), an oversized body `413 too_large`.
pub struct Json<T>(pub T);

impl<T: DeserializeOwned, S: Send + Sync> FromRequest<S> for Json<T> {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, Self::Rejection> {
        let bytes = read_body(req, state).await?;
        let de = &mut serde_json::Deserializer::from_slice(&bytes);
        let v = serde_path_to_error::deserialize(de).map_err(|e| {
            let path = e.path().to_string();
            ApiError::new(
                ErrorCode::InvalidJson,
                format!("unreadable JSON: {}", e.inner()),
            )
            .at(if path == "." { String::new() } else { path })
        })?;
        Ok(Json(v))
    }
}

impl<T: Serialize> IntoResponse for Json<T> {
    fn into_response(self) -> Response {
        axum::Json(self.0).into_response()
    }
}

async fn read_body<S: Send + Sync>(req: Request, state: &S) -> Result<Bytes, ApiError> {
    Bytes::from_request(req, state).await.map_err(|r| {
        if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
            ApiError::new(
                ErrorCode::TooLarge,
                "the request body is larger than the server's limit",
            )
        } else {
            ApiError::new(
                ErrorCode::InvalidJson,
                format!("could not read the request body: {}", r.body_text()),
            )
        }
    })
}

/// The raw body of `POST /v1/jobs`, read only once its bytes fit in the validation
/// budget (`AppState::uploads`): the permit travels with the body until validation ends.
/// The content type is checked before (`check_origin`, without a token); a UTF-8 byte
/// order mark is skipped (Windows editors write one; JSON forbids it, RFC 8259 §8.1).
pub struct SceneBody(pub SceneContent, pub tokio::sync::OwnedSemaphorePermit);

/// What a submission holds.
pub enum SceneContent {
    /// A scene document (`application/json`).
    Json(String),
    /// A file to import (scene-import.md): `model/gltf-binary` or `application/zip`.
    Upload(crate::import::Upload, Bytes),
}

impl FromRequest<AppState> for SceneBody {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &AppState) -> Result<Self, Self::Rejection> {
        if let Some(enc) = req
            .headers()
            .get(header::CONTENT_ENCODING)
            .filter(|v| !v.as_bytes().eq_ignore_ascii_case(b"identity"))
        {
            return Err(ApiError::new(
                ErrorCode::UnsupportedMediaType,
                format!(
                    "Content-Encoding {:?} is not supported; send the document unencoded",
                    clip(&String::from_utf8_lossy(enc.as_bytes()))
                ),
            ));
        }
        let upload = match req
            .headers()
            .get(header::CONTENT_TYPE)
            .and_then(|v| v.to_str().ok())
            .map(|v| {
                v.split(';')
                    .next()
                    .unwrap_or("")
                    .trim()
                    .to_ascii_lowercase()
            })
            .as_deref()
        {
            Some("model/gltf-binary") => Some(crate::import::Upload::Glb),
            Some("application/zip" | "application/x-zip-compressed") => {
                Some(crate::import::Upload::Zip)
            }
            _ => None,
        };
        let declared = req
            .headers()
            .get(header::CONTENT_LENGTH)
            .and_then(|v| v.to_str().ok()?.parse::<usize>().ok())
            .unwrap_or(state.max_body_bytes)
            .min(state.max_body_bytes);
        let kib = u32::try_from(declared.div_ceil(1024).max(1))
            .unwrap_or(u32::MAX)
            .min(u32::try_from(state.upload_budget_kib).unwrap_or(u32::MAX));
        let permit = acquire_budget(state, kib).await?;
        let bytes = read_body(req, state).await.map_err(|mut e| {
            if e.code == ErrorCode::TooLarge {
                e.message = format!(
                    "the request body is larger than the limit of {} bytes; the server's operator can raise it with `glimpse serve --max-body`",
                    state.max_body_bytes
                );
            }
            e
        })?;
        if let Some(kind) = upload {
            let permit = if kind == crate::import::Upload::Zip {
                charge_unpacked(state, permit, &bytes).await?
            } else {
                permit
            };
            return Ok(SceneBody(SceneContent::Upload(kind, bytes), permit));
        }
        let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&bytes);
        if bytes.iter().all(u8::is_ascii_whitespace) {
            return Err(ApiError::new(
                ErrorCode::InvalidJson,
                "the request body is empty; send a scene document",
            ));
        }
        let text = String::from_utf8(bytes.to_vec()).map_err(|e| {
            ApiError::new(
                ErrorCode::InvalidJson,
                format!("the body is not UTF-8: {e}"),
            )
        })?;
        Ok(SceneBody(SceneContent::Json(text), permit))
    }
}

/// `kib` permits of the validation budget. Waiting for room in the budget is the server's
/// doing, not the client's: past a third of the request deadline the client is told to
/// come back (503) rather than run into the deadline (408, which blames it).
async fn acquire_budget(
    state: &AppState,
    kib: u32,
) -> Result<tokio::sync::OwnedSemaphorePermit, ApiError> {
    let wait = state.request_deadline / 3;
    match tokio::time::timeout(wait, Arc::clone(&state.uploads).acquire_many_owned(kib)).await {
        Ok(Ok(permit)) => Ok(permit),
        Ok(Err(_)) => Err(ApiError::unavailable(
            "the server is shutting down; retry later",
            5,
        )),
        Err(_) => Err(ApiError::unavailable(
            "the server is busy validating other submissions; retry later",
            5,
        )),
    }
}

/// A zip is charged what it may unpack to (its directory's declared sizes, nothing
/// inflated) besides its body, capped at the whole budget as a large body is: measured
/// before, eight 250 KB zips of 250 MiB of zeros each were all accepted at once and took
/// the server to 1.9 GB. The rest is taken at once if free; otherwise the body's permits
/// are given back and the whole charge waited for (two requests each holding part while
/// waiting for more would wait on each other until the deadline).
async fn charge_unpacked(
    state: &AppState,
    mut permit: tokio::sync::OwnedSemaphorePermit,
    zip: &[u8],
) -> Result<tokio::sync::OwnedSemaphorePermit, ApiError> {
    let unpacked = crate::import::bundle::unpacked_size(zip).unwrap_or(0);
    let charge = (zip.len() as u64)
        .saturating_add(unpacked)
        .div_ceil(1024)
        .min(state.upload_budget_kib as u64);
    let (charge, held) = (
        u32::try_from(charge).unwrap_or(u32::MAX),
        u32::try_from(permit.num_permits()).unwrap_or(u32::MAX),
    );
    if charge <= held {
        return Ok(permit);
    }
    if let Ok(more) = Arc::clone(&state.uploads).try_acquire_many_owned(charge - held) {
        permit.merge(more);
        return Ok(permit);
    }
    drop(permit);
    acquire_budget(state, charge).await
}

/// Render settings of an upload from the query (`?spp=64&width=640&height=480&mode=...`).
fn upload_settings(q: &HashMap<String, String>) -> Result<crate::import::UploadSettings, ApiError> {
    let num = |k: &str| -> Result<Option<u64>, ApiError> {
        q.get(k)
            .map(|v| {
                v.parse::<u64>().map_err(|_| {
                    ApiError::new(
                        ErrorCode::InvalidParameter,
                        format!("?{k}= must be a non-negative integer, got \"{v}\""),
                    )
                    .at(k)
                })
            })
            .transpose()
    };
    let mode = match q.get("mode").map(String::as_str) {
        None => None,
        Some("progressive") => Some(RenderMode::Progressive),
        Some("guo") => Some(RenderMode::Guo),
        Some("reference") => Some(RenderMode::Reference),
        Some(other) => {
            return Err(ApiError::new(
                ErrorCode::InvalidParameter,
                format!("?mode= must be progressive, guo or reference, got \"{other}\""),
            )
            .at("mode"))
        }
    };
    Ok(crate::import::UploadSettings {
        width: num("width")?,
        height: num("height")?,
        samples_per_pixel: num("spp")?,
        mode,
        seed: num("seed")?,
    })
}

/// A job id from the path. Anything that is not a UUID is simply a job that does not
/// exist (404), never a 400: ids are opaque to clients.
pub struct JobId(pub Uuid);

impl<S: Send + Sync> FromRequestParts<S> for JobId {
    type Rejection = ApiError;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        state: &S,
    ) -> Result<Self, ApiError> {
        let axum::extract::Path(raw) =
            axum::extract::Path::<String>::from_request_parts(parts, state)
                .await
                .map_err(|_| ApiError::new(ErrorCode::NotFound, "no such job"))?;
        Uuid::parse_str(&raw)
            .map(JobId)
            .map_err(|_| ApiError::not_found_job(&raw))
    }
}

/// Query parameters as a map (unknown ones are ignored: `token=` rides along).
pub struct Params(pub HashMap<String, String>);

impl<S: Send + Sync> FromRequestParts<S> for Params {
    type Rejection = ApiError;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        state: &S,
    ) -> Result<Self, ApiError> {
        axum::extract::Query::<HashMap<String, String>>::from_request_parts(parts, state)
            .await
            .map(|q| Params(q.0))
            .map_err(|e| {
                ApiError::new(
                    ErrorCode::InvalidParameter,
                    format!("unreadable query string: {e}"),
                )
            })
    }
}

// ---------------------------------------------------------------------------------------
// Router

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

async fn not_found() -> ApiError {
    ApiError::new(ErrorCode::NotFound, "no such route")
}

async fn viewer() -> impl IntoResponse {
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        super::viewer::INDEX_HTML,
    )
}

/// `200 {"status": "ok"}`, or `503` with `"status": "store_fault"` beside the error shape
/// while the store's disk refuses writes (jobs wait, submissions get 503; it clears by
/// itself once a write succeeds again).
async fn healthz(State(st): State<AppState>) -> Response {
    let (status, message) = match (st.jobs.store_fault(), st.jobs.ping_store().await) {
        (None, Ok(())) => {
            let body = Health {
                status: "ok",
                database: Some(st.jobs.store_backend()),
                error: None,
            };
            return axum::Json(body).into_response();
        }
        // cluster.md: `/healthz` says whether the node reaches its database.
        (_, Err(e)) => (
            "database_unreachable",
            format!("this node cannot reach its job database: {e}"),
        ),
        (Some(fault), Ok(())) => (
            "store_fault",
            format!("the job store cannot be written: {fault}"),
        ),
    };
    let body = Health {
        status,
        database: None,
        error: Some(ApiError::unavailable(message, STORE_RETRY_AFTER_S).detail()),
    };
    let mut res = (StatusCode::SERVICE_UNAVAILABLE, axum::Json(body)).into_response();
    res.headers_mut()
        .insert(header::RETRY_AFTER, HeaderValue::from(STORE_RETRY_AFTER_S));
    res
}

/// `/healthz`'s body: `ok` with the store's backend, or what is wrong in the error shape.
#[derive(Serialize)]
struct Health {
    status: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    database: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<ErrorDetail>,
}

async fn metrics(State(st): State<AppState>) -> impl IntoResponse {
    let text = super::metrics::render(&st.metrics, &st.jobs.store_counts().await);
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        text,
    )
}

// ---------------------------------------------------------------------------------------
// Handlers

/// Longest job name (characters). It is repeated in every log line about the job and in
/// every list entry: measured before, a 7 MB name made a 217 MB log over 31 jobs and a
/// 210 MB answer to `GET /v1/jobs`.
pub const MAX_NAME_CHARS: usize = 256;

/// The 201 answer: the job, and what an import had to approximate or supply.
#[derive(Serialize)]
struct Created {
    #[serde(flatten)]
    job: JobRecord,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    warnings: Vec<String>,
}

async fn create_job(
    State(st): State<AppState>,
    Params(query): Params,
    SceneBody(body, permit): SceneBody,
) -> Result<Response, ApiError> {
    // Validation can be heavy (8 MiB of mesh): off the async runtime. A panic inside the
    // parser becomes a 500, never a dead server. An upload is imported into a scene
    // document first; the job stores that document, so a restart parses it again.
    let limits = *st.jobs.limits();
    let settings = match &body {
        SceneContent::Upload(..) => Some(upload_settings(&query)?),
        SceneContent::Json(_) => None,
    };
    let (text, parsed, warnings) = tokio::task::spawn_blocking(move || {
        let (text, warnings) = match body {
            SceneContent::Json(text) => (text, Vec::new()),
            SceneContent::Upload(kind, bytes) => {
                let s = settings.unwrap_or_default();
                match crate::import::import_upload(kind, &bytes, &s, &limits) {
                    Ok(r) => r,
                    Err(e) => return (String::new(), Err(e), Vec::new()),
                }
            }
        };
        let r = parse_scene(&text, &SceneOrigin::Request, &limits);
        (text, r, warnings)
    })
    .await
    .map_err(|e| ApiError::internal("validating the scene", &e))?;
    drop(permit);
    let scene = parsed.map_err(|mut e| {
        let code = match e.kind {
            SceneErrorKind::InvalidJson => ErrorCode::InvalidJson,
            SceneErrorKind::InvalidScene => ErrorCode::InvalidScene,
            // A parameter above a limit is not a body too large (413): 422 with the flag
            // that raises it.
            SceneErrorKind::TooLarge => ErrorCode::OverLimit,
        };
        for p in &mut e.problems {
            p.message = with_raise_hint(&p.path, &p.message);
        }
        let first = e.problems.first();
        let mut err = ApiError::new(
            code,
            first.map_or_else(|| "invalid scene".to_owned(), |p| p.message.clone()),
        )
        .at(first.map(|p| p.path.clone()).unwrap_or_default());
        err.problems = e.problems;
        err
    })?;
    let chars = scene.name.chars().count();
    if chars > MAX_NAME_CHARS {
        return Err(ApiError::new(
            ErrorCode::InvalidScene,
            format!("the name has {chars} characters; at most {MAX_NAME_CHARS} are allowed"),
        )
        .at("name"));
    }
    // What the import approximated, then what is valid but almost surely wrong.
    let warnings: Vec<String> = warnings
        .into_iter()
        .chain(scene.warnings.iter().map(|w| {
            Problem {
                path: w.path.clone(),
                message: with_raise_hint(&w.path, &w.message),
            }
            .to_string()
        }))
        .collect();
    let name = if scene.name.trim().is_empty() {
        "untitled".to_owned()
    } else {
        scene.name.clone()
    };
    let job = st
        .jobs
        .submit_parsed(&name, &text, Some(scene))
        .await
        .map_err(|e| match e {
            SubmitError::QueueFull(n) => {
                let mut err = ApiError::new(
                    ErrorCode::QueueFull,
                    format!("the queue is full ({n} jobs waiting); retry later"),
                );
                err.retry_after_s = Some(retry_after(n));
                err
            }
            SubmitError::ShuttingDown => {
                let mut err = ApiError::new(
                    ErrorCode::Unavailable,
                    "the server is shutting down; retry later",
                );
                err.retry_after_s = Some(5);
                err
            }
            SubmitError::Store(e) => ApiError::from(e),
        })?;
    let mut headers = HeaderMap::new();
    if let Ok(v) = HeaderValue::from_str(&format!("/v1/jobs/{}", job.id)) {
        headers.insert(header::LOCATION, v);
    }
    Ok((
        StatusCode::CREATED,
        headers,
        Json(Created { job, warnings }),
    )
        .into_response())
}

/// Seconds to wait before retrying a full queue: grows with the backlog, 1 s to 60 s.
fn retry_after(waiting: usize) -> u32 {
    u32::try_from(waiting / 8).unwrap_or(u32::MAX).clamp(1, 60)
}

/// `?limit=` default and maximum (service-api.md).
const LIST_DEFAULT: u32 = 50;
const LIST_MAX: u32 = 500;

#[derive(Serialize)]
struct JobList {
    jobs: Vec<JobRecord>,
}

async fn list_jobs(
    State(st): State<AppState>,
    Params(q): Params,
) -> Result<Json<JobList>, ApiError> {
    let state = match q.get("state") {
        None => None,
        Some(s) => Some(JobState::parse(s).ok_or_else(|| {
            ApiError::new(
                ErrorCode::InvalidParameter,
                format!(
                    "unknown state {:?}; use queued, running, succeeded, failed or cancelled",
                    clip(s)
                ),
            )
            .at("state")
        })?),
    };
    let limit = match q.get("limit") {
        None => LIST_DEFAULT,
        Some(s) => match s.parse::<u32>() {
            Ok(n) if (1..=LIST_MAX).contains(&n) => n,
            _ => {
                return Err(ApiError::new(
                    ErrorCode::InvalidParameter,
                    format!(
                        "limit must be an integer from 1 to {LIST_MAX}, got {:?}",
                        clip(s)
                    ),
                )
                .at("limit"))
            }
        },
    };
    Ok(Json(JobList {
        jobs: st.jobs.list(state, limit).await?,
    }))
}

async fn get_job(
    State(st): State<AppState>,
    JobId(id): JobId,
) -> Result<Json<JobRecord>, ApiError> {
    st.jobs
        .get(id)
        .await?
        .map(Json)
        .ok_or_else(|| ApiError::not_found_job(&id.to_string()))
}

/// The job's scene document byte for byte as submitted (its keys' order, spacing and
/// comments-free JSON as written), so a client can inspect or edit and re-submit it.
async fn get_scene(State(st): State<AppState>, JobId(id): JobId) -> Result<Response, ApiError> {
    let text = st
        .jobs
        .scene(id)
        .await?
        .ok_or_else(|| ApiError::not_found_job(&id.to_string()))?;
    Ok(([(header::CONTENT_TYPE, "application/json")], text).into_response())
}

async fn cancel_job(State(st): State<AppState>, JobId(id): JobId) -> Result<Response, ApiError> {
    match st.jobs.cancel(id).await? {
        CancelOutcome::NotFound => Err(ApiError::not_found_job(&id.to_string())),
        CancelOutcome::AlreadyFinished(j) => Err(ApiError::new(
            ErrorCode::Conflict,
            format!(
                "job {id} is already {}; nothing to cancel",
                j.state.as_str()
            ),
        )),
        CancelOutcome::Accepted(j) => Ok((StatusCode::ACCEPTED, Json(j)).into_response()),
    }
}

async fn delete_job(State(st): State<AppState>, JobId(id): JobId) -> Result<StatusCode, ApiError> {
    match st.jobs.delete(id).await? {
        DeleteOutcome::NotFound => Err(ApiError::not_found_job(&id.to_string())),
        DeleteOutcome::NotFinished(j) => Err(ApiError::new(
            ErrorCode::Conflict,
            format!("job {id} is still {}; cancel it first", j.state.as_str()),
        )),
        DeleteOutcome::Deleted => Ok(StatusCode::NO_CONTENT),
    }
}

async fn get_frame(
    State(st): State<AppState>,
    JobId(id): JobId,
    Params(q): Params,
) -> Result<Response, ApiError> {
    let layer_name = q.get("layer").map_or("image", String::as_str);
    let Some(layer) = Layer::parse(layer_name) else {
        let names: Vec<&str> = Layer::ALL.iter().map(|l| l.as_str()).collect();
        return Err(ApiError::new(
            ErrorCode::InvalidParameter,
            format!(
                "unknown layer {:?}; use one of {}",
                clip(layer_name),
                names.join(", ")
            ),
        )
        .at("layer"));
    };
    let exr = match q.get("format").map(String::as_str) {
        None | Some("png") => false,
        Some("exr") => true,
        Some(f) => {
            return Err(ApiError::new(
                ErrorCode::InvalidParameter,
                format!("unknown format {:?}; use png or exr", clip(f)),
            )
            .at("format"))
        }
    };
    if exr && layer != Layer::Image {
        return Err(ApiError::new(
            ErrorCode::InvalidParameter,
            "format=exr is only available for the image layer (the linear HDR radiance)",
        )
        .at("format"));
    }
    let iteration = iteration_param(&q, exr)?;
    let ctype = if exr { "image/x-exr" } else { "image/png" };
    let headers = [
        (header::CONTENT_TYPE, ctype),
        (header::CACHE_CONTROL, "no-store"),
    ];
    let found = match iteration {
        Some(n) => st.jobs.iteration_frame(id, n, layer).await?,
        None => st.jobs.frame(id, layer, exr).await?,
    };
    let path = match found {
        FrameLookup::Found(FrameBytes::Memory(bytes)) => {
            return Ok((headers, bytes).into_response())
        }
        FrameLookup::Found(FrameBytes::File(path)) => path,
        FrameLookup::NotFound => return Err(ApiError::not_found_job(&id.to_string())),
        FrameLookup::NoFrame => {
            return Err(ApiError::new(
                ErrorCode::NotFound,
                format!("job {id} has no frame yet"),
            ))
        }
        FrameLookup::NoLayer => return Err(missing_layer(layer)),
        FrameLookup::NoIteration(kept) => return Err(missing_iteration(iteration, &kept)),
        FrameLookup::EncodingFailed(e) => return Err(ApiError::internal("encoding a frame", &e)),
    };
    // Streamed from the file: a request holds a file handle and a small buffer, never the
    // file (a 4096² EXR is 201 MB; one copy per request let 20 clients that did not read
    // hold 3.8 GB).
    let file = match tokio::fs::File::open(&path).await {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Err(missing_layer(layer)),
        Err(e) => return Err(ApiError::internal("reading a stored frame", &e)),
    };
    let len = file
        .metadata()
        .await
        .map_err(|e| ApiError::internal("reading a stored frame", &e))?
        .len();
    let body = axum::body::Body::from_stream(tokio_util::io::ReaderStream::with_capacity(
        file, FILE_CHUNK,
    ));
    let mut res = (headers, body).into_response();
    res.headers_mut()
        .insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    Ok(res)
}

/// The `iteration` query parameter of `GET .../frame`: absent (the latest frame) or an
/// iteration number as the job's progress counts them (PNG layers only).
fn iteration_param(q: &HashMap<String, String>, exr: bool) -> Result<Option<u32>, ApiError> {
    let Some(text) = q.get("iteration") else {
        return Ok(None);
    };
    let n = text.parse::<u32>().map_err(|_| {
        ApiError::new(
            ErrorCode::InvalidParameter,
            format!(
                "iteration must be a whole number from 0 (as the job's progress counts them), not {:?}",
                clip(text)
            ),
        )
        .at("iteration")
    })?;
    if exr {
        return Err(ApiError::new(
            ErrorCode::InvalidParameter,
            "format=exr is only available for the latest frame; earlier iterations are kept as PNG",
        )
        .at("format"));
    }
    Ok(Some(n))
}

fn missing_iteration(iteration: Option<u32>, kept: &[u32]) -> ApiError {
    let n = iteration.map_or_else(String::new, |n| format!(" {n}"));
    let which = match (kept.first(), kept.last()) {
        (Some(a), Some(b)) => format!(
            "{} iterations from {a} to {b} are (GET .../iterations lists them)",
            kept.len()
        ),
        _ => "no iteration is kept yet".to_owned(),
    };
    ApiError::new(
        ErrorCode::NotFound,
        format!("iteration{n} of this job is not kept; {which}"),
    )
    .at("iteration")
}

/// The iterations of a job whose frames can be had (`GET .../frame?iteration=N`).
async fn get_iterations(
    State(st): State<AppState>,
    JobId(id): JobId,
) -> Result<Json<IterationList>, ApiError> {
    st.jobs
        .iterations(id)
        .await?
        .map(|iterations| Json(IterationList { iterations }))
        .ok_or_else(|| ApiError::not_found_job(&id.to_string()))
}

#[derive(Serialize)]
struct IterationList {
    iterations: Vec<crate::service::jobs::KeptIteration>,
}

fn missing_layer(layer: Layer) -> ApiError {
    ApiError::new(
        ErrorCode::NotFound,
        format!("this frame has no {} layer", layer.as_str()),
    )
    .at("layer")
}

/// Read size when streaming a stored file.
const FILE_CHUNK: usize = 16 * 1024;

/// The `glimpse serve` flag that raises the limit a problem (or the bounce cap a warning)
/// at `path` names, from validation's and the importers' own wording (`scene::validate`:
/// "exceeds this server's limit", "above this server's cap"; "the limit of N
/// triangles"); `None` for anything else and for the fixed limits (texels, file sizes,
/// bundle entries).
fn raise_flag(path: &str, message: &str) -> Option<&'static str> {
    // The importers' triangle limits are the scene's (`ImportLimits::from_scene`).
    if message.contains("limit of") && message.contains(" triangles") {
        return Some("--max-triangles");
    }
    if !message.contains("this server's limit") && !message.contains("this server's cap") {
        return None;
    }
    Some(match path {
        "image.width" => "--max-width",
        "image.height" => "--max-height",
        "image" => "--max-pixels",
        "render.samples_per_pixel" if message.contains("samples per render") => "--max-samples",
        "render.samples_per_pixel" => "--max-spp",
        "render.max_bounces" => "--max-bounces",
        _ if message.contains(" objects exceed") => "--max-objects",
        _ if message.contains(" triangles exceed") => "--max-triangles",
        _ => return None,
    })
}

/// `message` with the flag that raises its limit appended, when there is one.
fn with_raise_hint(path: &str, message: &str) -> String {
    match raise_flag(path, message) {
        Some(flag) => {
            format!("{message}; the server's operator can raise it with `glimpse serve {flag}`")
        }
        None => message.to_owned(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn parameter_limits_name_the_flag_that_raises_them() {
        for (path, message, flag) in [
            ("image.width", "20000 exceeds this server's limit of 4096", "--max-width"),
            ("image", "5000×5000 = 25000000 pixels exceeds this server's limit of 16777216 pixels", "--max-pixels"),
            ("render.samples_per_pixel", "5000 exceeds this server's limit of 4096", "--max-spp"),
            ("render.samples_per_pixel", "4096 samples × 4194304 pixels = 17179869184 samples exceeds this server's limit of 4294967296 samples per render", "--max-samples"),
            ("render.max_bounces", "5000 is above this server's cap of 1024: paths stop", "--max-bounces"),
            ("objects", "10001 objects exceed this server's limit of 10000", "--max-objects"),
            ("objects", "12 triangles exceed this server's limit of 11", "--max-triangles"),
            ("scene.pbrt:3:1", "the scene has more than the limit of 11 triangles", "--max-triangles"),
        ] {
            assert_eq!(raise_flag(path, message), Some(flag), "{path}: {message}");
            assert!(with_raise_hint(path, message).ends_with(&format!("`glimpse serve {flag}`")));
        }
        assert_eq!(
            raise_flag(
                "bundle",
                "the bundle has 10001 entries, more than the limit of 10000"
            ),
            None
        );
        assert_eq!(raise_flag("render.max_bounces", "must be ≥ 0"), None);
        assert_eq!(
            ErrorCode::OverLimit.status(),
            StatusCode::UNPROCESSABLE_ENTITY
        );
    }

    #[test]
    fn error_body_has_code_message_path() {
        let e = ApiError::new(ErrorCode::QueueFull, "full").at("x");
        assert_eq!(
            serde_json::to_value(e.body()).unwrap(),
            json!({"error": {"code": "queue_full", "message": "full", "path": "x"}})
        );
        assert_eq!(ErrorCode::QueueFull.status(), StatusCode::TOO_MANY_REQUESTS);
        assert_eq!(
            ErrorCode::InvalidScene.status(),
            StatusCode::UNPROCESSABLE_ENTITY
        );
    }

    #[test]
    fn retry_after_is_bounded() {
        assert_eq!(retry_after(0), 1);
        assert_eq!(retry_after(64), 8);
        assert_eq!(retry_after(usize::MAX), 60);
    }

    #[derive(Debug, serde::Deserialize)]
    struct Body {
        #[allow(dead_code)]
        a: Vec<u32>,
    }

    async fn extract(body: &'static str) -> Result<Json<Body>, ApiError> {
        let req = axum::http::Request::builder()
            .method("POST")
            .uri("/")
            .body(axum::body::Body::from(body))
            .unwrap();
        Json::<Body>::from_request(req, &()).await
    }

    #[tokio::test]
    async fn json_extractor_reports_invalid_json_with_the_path() {
        assert!(extract(r#"{"a": [1, 2]}"#).await.is_ok());
        let e = extract(r#"{"a": [1, -2]}"#).await.err().unwrap();
        assert_eq!((e.code, e.path.as_str()), (ErrorCode::InvalidJson, "a[1]"));
        let e = extract("{").await.err().unwrap();
        assert_eq!(e.code, ErrorCode::InvalidJson);
        let e = extract(r#"{"a": [NaN]}"#).await.err().unwrap();
        assert_eq!(e.code, ErrorCode::InvalidJson);
    }
}
