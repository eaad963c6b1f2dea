//! The stable machine-readable error codes of service-api.md "Errors", shared by the
//! HTTP answers (`http::ApiError`) and the `error` of a failed job (`store::JobError`).

use axum::http::StatusCode;
use serde::{Deserialize, Serialize};

/// The stable machine-readable error codes of service-api.md "Errors".
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    InvalidJson,
    InvalidScene,
    InvalidParameter,
    /// Not valid HTTP/1.1 (a malformed header, a repeated `Content-Length`): hyper's own
    /// answer, given the error body by `parse_error`.
    InvalidRequest,
    /// The request body (or a URI or header) is larger than the server accepts (413; 414
    /// and 431 for hyper's own answers).
    TooLarge,
    /// A parameter of the scene (pixels, samples, samples × pixels, objects, triangles,
    /// texels, files in a bundle) is above this server's limit: the document is fine, the
    /// server will not do that much (422; the message names the limit and the flag that
    /// raises it).
    OverLimit,
    NotFound,
    MethodNotAllowed,
    Conflict,
    QueueFull,
    Unauthorized,
    Unavailable,
    /// The job database cannot be reached (PostgreSQL down or cut off from this node):
    /// 503 like `unavailable`, but the fault is the database's connection, not a disk.
    DatabaseUnreachable,
    /// The scene asks to be denoised (`render.denoise`, or adaptive mode by default) and
    /// this server has no Intel Open Image Denoise library (503: the server lacks it, the
    /// scene is fine; the message says how to add it, or to set `render.denoise` false).
    DenoiserUnavailable,
    /// The job's record is there but its stored files are gone (removed outside the
    /// server, or a disk replaced): 410, for good; the job has to be submitted again.
    FilesMissing,
    /// The request (headers aside) was not received and answered within
    /// [`REQUEST_DEADLINE`]: a client trickling its body.
    RequestTimeout,
    /// A body that is not a scene document's or an import's type, or that is encoded.
    UnsupportedMediaType,
    /// `Host` names another server (DNS rebinding), without a token.
    MisdirectedRequest,
    /// A request from a page of another origin, without a token.
    Forbidden,
    Internal,
    // The codes of a failed job's `error` (never an HTTP answer's).
    /// The render itself failed (a panic inside it, caught at the job's boundary).
    RenderFailed,
    /// The job asked to be denoised and the denoiser failed on its picture: the job fails
    /// with the denoiser's reason rather than end with a noisy picture.
    DenoiseFailed,
    /// The render ran longer than `--job-timeout`.
    Timeout,
    /// Every allowed attempt ended with its worker gone (killed, crashed, or its lease
    /// lost): the job is not run again.
    Poison,
}

impl ErrorCode {
    #[must_use]
    pub fn status(self) -> StatusCode {
        match self {
            ErrorCode::InvalidJson | ErrorCode::InvalidParameter | ErrorCode::InvalidRequest => {
                StatusCode::BAD_REQUEST
            }
            ErrorCode::InvalidScene | ErrorCode::OverLimit => StatusCode::UNPROCESSABLE_ENTITY,
            ErrorCode::TooLarge => StatusCode::PAYLOAD_TOO_LARGE,
            ErrorCode::NotFound => StatusCode::NOT_FOUND,
            ErrorCode::MethodNotAllowed => StatusCode::METHOD_NOT_ALLOWED,
            ErrorCode::Conflict => StatusCode::CONFLICT,
            ErrorCode::QueueFull => StatusCode::TOO_MANY_REQUESTS,
            ErrorCode::Unauthorized => StatusCode::UNAUTHORIZED,
            ErrorCode::Unavailable
            | ErrorCode::DatabaseUnreachable
            | ErrorCode::DenoiserUnavailable => StatusCode::SERVICE_UNAVAILABLE,
            ErrorCode::FilesMissing => StatusCode::GONE,
            ErrorCode::RequestTimeout => StatusCode::REQUEST_TIMEOUT,
            ErrorCode::UnsupportedMediaType => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            ErrorCode::MisdirectedRequest => StatusCode::MISDIRECTED_REQUEST,
            ErrorCode::Forbidden => StatusCode::FORBIDDEN,
            ErrorCode::Internal
            | ErrorCode::RenderFailed
            | ErrorCode::DenoiseFailed
            | ErrorCode::Timeout
            | ErrorCode::Poison => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }
}
