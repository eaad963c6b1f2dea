//! The REST handlers of service-api.md: jobs (submit, list, read, cancel, delete), their
//! scene, frames and iterations, `/healthz`, `/metrics` and the viewer page.

use super::error::*;
use super::extract::{upload_settings, JobId, Json, Params, SceneBody, SceneContent};
use super::jobs::{CancelOutcome, DeleteOutcome, FrameBytes, FrameLookup, SubmitError};
use super::state::AppState;
use super::store::{clip, JobRecord, JobState, Layer};
use crate::scene::{parse_scene, Problem, SceneError, SceneErrorKind, SceneOrigin};
use axum::extract::State;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use std::collections::HashMap;

pub(super) async fn not_found() -> ApiError {
    ApiError::new(ErrorCode::NotFound, "no such route")
}

pub(super) async fn viewer() -> impl IntoResponse {
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
pub(super) async fn healthz(State(st): State<AppState>) -> Response {
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
pub(super) struct Health {
    status: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    database: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<ErrorDetail>,
}

pub(super) async fn metrics(State(st): State<AppState>) -> impl IntoResponse {
    let text = super::metrics::render(&st.metrics, &st.jobs.store_counts().await);
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        text,
    )
}

/// Longest job name (characters). It is repeated in every log line about the job and in
/// every list entry: measured before, a 7 MB name made a 217 MB log over 31 jobs and a
/// 210 MB answer to `GET /v1/jobs`.
pub const MAX_NAME_CHARS: usize = 256;

/// `POST /v1/jobs`: the submission imported if it is a file, validated, checked, then
/// queued durably before the `201`, whose job carries what an import had to approximate
/// or supply and what is valid but almost surely wrong (`warnings`).
pub(super) async fn create_job(
    State(st): State<AppState>,
    Params(query): Params,
    SceneBody(body, permit): SceneBody,
) -> Result<Response, ApiError> {
    let limits = *st.jobs.limits();
    let settings = match &body {
        SceneContent::Upload(..) => Some(upload_settings(&query)?),
        SceneContent::Json(_) => None,
    };
    let (text, parsed, warnings) =
        validate(body, settings, limits, st.max_body_bytes as u64).await?;
    drop(permit);
    let scene = parsed.map_err(refused)?;
    // Refused now rather than failed later: a job asked to denoise is never rendered
    // without it.
    if let Err(e) = crate::progressive::denoiser_for(&scene, &Default::default()) {
        return Err(ApiError::new(
            ErrorCode::DenoiserUnavailable,
            format!("{e}; or set render.denoise to false"),
        )
        .at("render.denoise"));
    }
    within_job_memory(&scene, st.jobs.job_memory())?;
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
    // The job keeps its warnings: the 201 shows them, and so does every later answer
    // about the job (a viewer or a poller may never see the 201).
    let job = st
        .jobs
        .submit_parsed(&name, &text, Some(scene), &warnings)
        .await
        .map_err(not_queued)?;
    let mut headers = HeaderMap::new();
    if let Ok(v) = HeaderValue::from_str(&format!("/v1/jobs/{}", job.id)) {
        headers.insert(header::LOCATION, v);
    }
    Ok((StatusCode::CREATED, headers, Json(job)).into_response())
}

/// A submission's scene: its document (imported first if it is a file), parsed and
/// validated, with the import's warnings. Validation can be heavy (8 MiB of mesh): off the
/// async runtime. A panic inside the parser becomes a 500, never a dead server. The job
/// stores the document, so a restart parses it again; a document in a bundle is held to
/// `max_document_bytes` as a posted one is.
async fn validate(
    body: SceneContent,
    settings: Option<crate::import::UploadSettings>,
    limits: crate::scene::Limits,
    max_document_bytes: u64,
) -> Result<(String, Result<crate::scene::Scene, SceneError>, Vec<String>), ApiError> {
    tokio::task::spawn_blocking(move || {
        let (text, warnings) = match body {
            SceneContent::Json(text) => (text, Vec::new()),
            SceneContent::Upload(kind, bytes) => {
                let s = settings.unwrap_or_default();
                match crate::import::import_upload(kind, &bytes, &s, &limits, max_document_bytes) {
                    Ok(r) => r,
                    Err(e) => return (String::new(), Err(e), Vec::new()),
                }
            }
        };
        let r = parse_scene(&text, &SceneOrigin::Request, &limits);
        (text, r, warnings)
    })
    .await
    .map_err(|e| ApiError::internal("validating the scene", &e))
}

/// Refused now rather than killed later: a job whose size, mode and denoiser would need
/// more memory than this server gives one job (`--max-job-memory`).
fn within_job_memory(scene: &crate::scene::Scene, budget: u64) -> Result<(), ApiError> {
    use crate::progressive::memory::{human_bytes, MemoryEstimate};
    let need = MemoryEstimate::of(scene, &Default::default()).least_bytes();
    if need <= budget {
        return Ok(());
    }
    let mode = scene.render.mode.as_str();
    let with = if crate::progressive::wants_denoise(scene, &Default::default()) {
        " with the denoiser"
    } else {
        ""
    };
    Err(ApiError::new(
        ErrorCode::OverLimit,
        format!(
            "a {}×{} render in {mode} mode{with} needs about {} of memory, more than this server's limit of {} per job; render a smaller image, or the server's operator can raise it with `glimpse serve --max-job-memory`",
            scene.width,
            scene.height,
            human_bytes(need),
            human_bytes(budget)
        ),
    )
    .at("image"))
}

/// A refused scene as an answer: every problem listed, the first as the headline.
fn refused(mut e: SceneError) -> ApiError {
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
}

/// Why a valid scene was not queued.
fn not_queued(e: SubmitError) -> ApiError {
    match e {
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
    }
}

/// Seconds to wait before retrying a full queue: grows with the backlog, 1 s to 60 s.
pub(super) fn retry_after(waiting: usize) -> u32 {
    u32::try_from(waiting / 8).unwrap_or(u32::MAX).clamp(1, 60)
}

/// `?limit=` default and maximum (service-api.md).
pub(super) const LIST_DEFAULT: u32 = 50;

pub(super) const LIST_MAX: u32 = 500;

#[derive(Serialize)]
pub(super) struct JobList {
    jobs: Vec<JobRecord>,
}

pub(super) async fn list_jobs(
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

pub(super) async fn get_job(
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
pub(super) async fn get_scene(
    State(st): State<AppState>,
    JobId(id): JobId,
) -> Result<Response, ApiError> {
    let text = st
        .jobs
        .scene(id)
        .await?
        .ok_or_else(|| ApiError::not_found_job(&id.to_string()))?;
    Ok(([(header::CONTENT_TYPE, "application/json")], text).into_response())
}

pub(super) async fn cancel_job(
    State(st): State<AppState>,
    JobId(id): JobId,
) -> Result<Response, ApiError> {
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

pub(super) async fn delete_job(
    State(st): State<AppState>,
    JobId(id): JobId,
) -> Result<StatusCode, ApiError> {
    match st.jobs.delete(id).await? {
        DeleteOutcome::NotFound => Err(ApiError::not_found_job(&id.to_string())),
        DeleteOutcome::NotFinished(j) => Err(ApiError::new(
            ErrorCode::Conflict,
            format!("job {id} is still {}; cancel it first", j.state.as_str()),
        )),
        DeleteOutcome::Deleted => Ok(StatusCode::NO_CONTENT),
    }
}

pub(super) async fn get_frame(
    State(st): State<AppState>,
    JobId(id): JobId,
    Params(q): Params,
) -> Result<Response, ApiError> {
    let (layer, exr) = frame_params(&q)?;
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
    stream_file(&path, layer, headers).await
}

/// The `layer` and `format` query parameters of `GET .../frame` (EXR for the image only).
fn frame_params(q: &HashMap<String, String>) -> Result<(Layer, bool), ApiError> {
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
    Ok((layer, exr))
}

/// A stored frame's file as the answer's body.
async fn stream_file(
    path: &std::path::Path,
    layer: Layer,
    headers: [(header::HeaderName, &'static str); 2],
) -> Result<Response, ApiError> {
    // Streamed from the file: a request holds a file handle and a small buffer, never the
    // file (a 4096² EXR is 201 MB; one copy per request let 20 clients that did not read
    // hold 3.8 GB).
    let file = match tokio::fs::File::open(path).await {
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
pub(super) fn iteration_param(
    q: &HashMap<String, String>,
    exr: bool,
) -> Result<Option<u32>, ApiError> {
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

pub(super) fn missing_iteration(iteration: Option<u32>, kept: &[u32]) -> ApiError {
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
pub(super) async fn get_iterations(
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
pub(super) struct IterationList {
    iterations: Vec<crate::service::jobs::KeptIteration>,
}

pub(super) fn missing_layer(layer: Layer) -> ApiError {
    ApiError::new(
        ErrorCode::NotFound,
        format!("this frame has no {} layer", layer.as_str()),
    )
    .at("layer")
}

/// Read size when streaming a stored file.
pub(super) const FILE_CHUNK: usize = 16 * 1024;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn retry_after_is_bounded() {
        assert_eq!(retry_after(0), 1);
        assert_eq!(retry_after(64), 8);
        assert_eq!(retry_after(usize::MAX), 60);
    }
}
