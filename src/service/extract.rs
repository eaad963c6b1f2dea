//! Our extractors: each maps axum's rejection to an [`ApiError`] (JSON bodies with the
//! path where they failed, a submission within the validation budget, job ids, query
//! parameters).

use super::error::{ApiError, ErrorCode};
use super::state::AppState;
use super::store::clip;
use crate::scene::RenderMode;
use axum::extract::{FromRequest, FromRequestParts, Request};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::collections::HashMap;
use std::sync::Arc;
use uuid::Uuid;

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

pub(super) async fn read_body<S: Send + Sync>(req: Request, state: &S) -> Result<Bytes, ApiError> {
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
        if req.headers().get_all(header::CONTENT_TYPE).iter().count() > 1 {
            return Err(ApiError::new(
                ErrorCode::InvalidRequest,
                "Content-Type is given more than once; give it once",
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
pub(super) async fn acquire_budget(
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
pub(super) async fn charge_unpacked(
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

/// Render settings of an upload from the query (`?spp=64&width=640&height=480&mode=...`,
/// `denoise=true|false`, `sampler=independent|sobol|zsobol`).
pub(super) fn upload_settings(
    q: &HashMap<String, String>,
) -> Result<crate::import::UploadSettings, ApiError> {
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
        Some("adaptive") => Some(RenderMode::Adaptive),
        Some(other) => {
            return Err(ApiError::new(
                ErrorCode::InvalidParameter,
                format!("?mode= must be progressive, guo, reference or adaptive, got \"{other}\""),
            )
            .at("mode"))
        }
    };
    let denoise = match q.get("denoise").map(String::as_str) {
        None => None,
        Some("true") => Some(true),
        Some("false") => Some(false),
        Some(other) => {
            return Err(ApiError::new(
                ErrorCode::InvalidParameter,
                format!("?denoise= must be true or false, got \"{}\"", clip(other)),
            )
            .at("denoise"))
        }
    };
    let sampler = match q.get("sampler") {
        None => None,
        Some(s) => Some(
            <crate::scene::SamplerKind as serde::Deserialize>::deserialize(
                serde::de::value::StrDeserializer::<serde::de::value::Error>::new(s),
            )
            .map_err(|_| {
                ApiError::new(
                    ErrorCode::InvalidParameter,
                    format!(
                        "?sampler= must be independent, sobol or zsobol, got \"{}\"",
                        clip(s)
                    ),
                )
                .at("sampler")
            })?,
        ),
    };
    Ok(crate::import::UploadSettings {
        width: num("width")?,
        height: num("height")?,
        samples_per_pixel: num("spp")?,
        mode,
        seed: num("seed")?,
        denoise,
        sampler,
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
        let pairs = axum::extract::Query::<Vec<(String, String)>>::from_request_parts(parts, state)
            .await
            .map_err(|e| {
                ApiError::new(
                    ErrorCode::InvalidParameter,
                    format!("unreadable query string: {e}"),
                )
            })?
            .0;
        // `?width=8&width=9` is ambiguous: refused rather than one of them kept silently.
        let mut map = HashMap::with_capacity(pairs.len());
        for (k, v) in pairs {
            if map.contains_key(&k) {
                return Err(ApiError::new(
                    ErrorCode::InvalidParameter,
                    format!("?{}= is given more than once; give it once", clip(&k)),
                )
                .at(clip(&k)));
            }
            map.insert(k, v);
        }
        Ok(Params(map))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
    async fn a_repeated_query_parameter_is_refused_naming_it() {
        let params = |uri: &'static str| async move {
            let (mut parts, ()) = axum::http::Request::builder()
                .uri(uri)
                .body(())
                .unwrap()
                .into_parts();
            Params::from_request_parts(&mut parts, &()).await
        };
        let Params(q) = params("/?width=8&height=9").await.ok().unwrap();
        assert_eq!((q["width"].as_str(), q["height"].as_str()), ("8", "9"));
        let e = params("/?width=8&width=9").await.err().unwrap();
        assert_eq!(
            (e.code, e.path.as_str()),
            (ErrorCode::InvalidParameter, "width")
        );
        assert!(e.message.contains("more than once"), "{}", e.message);
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
