//! [`ApiError`], the only type that knows HTTP status codes, and the JSON error shape
//! every answer leaves in: our handlers return it, our extractors map axum's rejections
//! to it, and [`json_errors`] rewrites whatever else axum or tower-http produce on their
//! own (unknown route, wrong method, body over the limit), so a client never has to parse
//! plain text.

use super::state::AppState;
use super::store::{clip, Failure, StoreError};
use axum::extract::State;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use std::sync::atomic::Ordering;

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
pub(super) const STORE_RETRY_AFTER_S: u32 = 30;

/// `Retry-After` when the database cannot be reached: a restart or a failover takes
/// seconds, and nothing is lost by asking again soon.
pub(super) const UNREACHABLE_RETRY_AFTER_S: u32 = 5;

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

/// The `glimpse serve` flag that raises the limit a problem (or the bounce cap a warning)
/// at `path` names, from validation's and the importers' own wording (`scene::validate`:
/// "exceeds this server's limit", "above this server's cap"; "the limit of N
/// triangles"); `None` for anything else and for the fixed limits (texels, file sizes,
/// bundle entries).
pub(super) fn raise_flag(path: &str, message: &str) -> Option<&'static str> {
    // Checked first: a glTF's object count names its triangles too.
    if message.contains(" objects exceed this server's limit") {
        return Some("--max-objects");
    }
    // The importers' triangle limits are the scene's (`ImportLimits::from_scene`).
    if message.contains("limit of") && message.contains(" triangles") {
        return Some("--max-triangles");
    }
    // A document in a bundle is held to a posted document's limit (`import_upload`).
    if message.contains("bytes for a scene document") {
        return Some("--max-body");
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
pub(super) fn with_raise_hint(path: &str, message: &str) -> String {
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
            ("scene.json", "the scene document unpacks to 9 bytes, more than the limit of 8 bytes for a scene document, posted or in a bundle (refused before unpacking)", "--max-body"),
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
}
