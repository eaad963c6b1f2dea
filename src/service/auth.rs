//! Access control for `/v1`: off by default; with a token, every `/v1` call
//! needs `Authorization: Bearer <token>`. WebSocket streams may pass `?token=` instead,
//! because browsers cannot set headers on a WebSocket. `/`, `/healthz` and `/metrics`
//! stay open (the viewer page asks for the token itself; probes need no secret).
//!
//! Without a token, any web page the server's user opens could otherwise drive it (a
//! probe found a cross-origin `text/plain` form post got 201; DNS rebinding got read, cancel and
//! delete). [`check_origin`] closes that: the `Host` must name this server, an `Origin`
//! must be this server's, and a submission must carry a scene or import content type,
//! which no form can send. No CORS header is ever sent, so other origins cannot read
//! answers either.

use super::error::{ApiError, ErrorCode};
use super::state::AppState;
use super::store::clip;
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::collections::HashMap;

pub async fn require_token(State(st): State<AppState>, req: Request, next: Next) -> Response {
    let Some(expected) = st.token.as_deref() else {
        return next.run(req).await;
    };
    let header_token = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(bearer_token);
    let ok = match header_token {
        Some(t) => constant_time_eq(t.as_bytes(), expected.as_bytes()),
        None if req.uri().path().ends_with("/stream") => {
            axum::extract::Query::<HashMap<String, String>>::try_from_uri(req.uri())
                .ok()
                .and_then(|q| q.0.get("token").cloned())
                .is_some_and(|t| constant_time_eq(t.as_bytes(), expected.as_bytes()))
        }
        None => false,
    };
    if ok {
        return next.run(req).await;
    }
    let mut res = ApiError::new(
        ErrorCode::Unauthorized,
        "this server needs a token: send `Authorization: Bearer <token>`",
    )
    .into_response();
    res.headers_mut()
        .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
    res
}

/// The token of an `Authorization` value with the `Bearer` scheme, which is
/// case-insensitive (RFC 9110 §11.1).
fn bearer_token(value: &str) -> Option<&str> {
    let (scheme, token) = value.trim_start().split_once(' ')?;
    scheme
        .eq_ignore_ascii_case("bearer")
        .then_some(token.trim())
}

/// Content types a submission may have: a scene document, or an import (scene-import.md).
const SUBMISSION_TYPES: [&str; 3] = ["application/json", "model/gltf-binary", "application/zip"];

/// Cross-site protection when the server has no token (see the module comment): `421`
/// for a foreign `Host`, `403` for a foreign `Origin`, `415` for a submission that is not
/// JSON or an import.
pub async fn check_origin(State(st): State<AppState>, req: Request, next: Next) -> Response {
    if st.token.is_some() {
        return next.run(req).await;
    }
    let headers = req.headers();
    let header_str = |name: header::HeaderName| {
        headers
            .get(name)
            .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned())
    };
    let host = header_str(header::HOST);
    let origin = header_str(header::ORIGIN);
    let ctype = header_str(header::CONTENT_TYPE).unwrap_or_default();
    if let Some(h) = host.as_deref().filter(|h| !st.origin.allows_host(h)) {
        return ApiError::new(
            ErrorCode::MisdirectedRequest,
            format!(
                "Host {:?} does not name this server; without a token only its address, localhost or a name given with --allowed-host is accepted",
                clip(h)
            ),
        )
        .into_response();
    }
    if let Some(o) = origin.filter(|o| !st.origin.allows_origin(o, host.as_deref())) {
        return ApiError::new(
            ErrorCode::Forbidden,
            format!(
                "requests from pages of other origins ({:?}) are refused without a token",
                clip(&o)
            ),
        )
        .into_response();
    }
    if req.method() == axum::http::Method::POST && req.uri().path() == "/v1/jobs" {
        let essence = ctype.split(';').next().unwrap_or("").trim();
        if !SUBMISSION_TYPES
            .iter()
            .any(|t| t.eq_ignore_ascii_case(essence))
        {
            return ApiError::new(
                ErrorCode::UnsupportedMediaType,
                format!(
                    "Content-Type {:?} is not a scene; send application/json (or an import: model/gltf-binary, application/zip)",
                    clip(&ctype)
                ),
            )
            .into_response();
        }
    }
    next.run(req).await
}

/// Compares without an early exit, so the time taken does not reveal how many leading
/// bytes of a guess were right. (The length is not secret enough to hide.)
#[must_use]
pub fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    let diff = a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y));
    std::hint::black_box(diff) == 0
}

#[cfg(test)]
mod tests {
    use super::{bearer_token, constant_time_eq};
    use crate::service::origin::OriginPolicy;

    #[test]
    fn the_bearer_scheme_is_case_insensitive() {
        assert_eq!(bearer_token("Bearer abc"), Some("abc"));
        assert_eq!(bearer_token("bearer abc"), Some("abc"));
        assert_eq!(bearer_token("BEARER  abc "), Some("abc"));
        assert_eq!(bearer_token("Basic abc"), None);
        assert_eq!(bearer_token("Bearerabc"), None);
    }

    #[test]
    fn hosts_and_origins_that_name_this_server() {
        let p = OriginPolicy::new(&["Render.Example.org".to_owned()]);
        for ok in [
            "127.0.0.1:8080",
            "localhost:8080",
            "[::1]:8080",
            "10.1.2.3",
            "a.localhost",
            "render.example.org:443",
        ] {
            assert!(p.allows_host(ok), "{ok}");
        }
        for bad in ["evil.example:8080", "localhost.evil.example", "example.org"] {
            assert!(!p.allows_host(bad), "{bad}");
        }
        assert!(p.allows_origin("http://127.0.0.1:8080", Some("127.0.0.1:8080")));
        assert!(p.allows_origin("https://render.example.org", Some("10.0.0.1:8080")));
        assert!(!p.allows_origin("http://127.0.0.1:9999", Some("127.0.0.1:8080")));
        assert!(!p.allows_origin("http://evil.example", Some("127.0.0.1:8080")));
        assert!(!p.allows_origin("null", Some("127.0.0.1:8080")));
    }

    #[test]
    fn compares_bytes_exactly() {
        assert!(constant_time_eq(b"secret", b"secret"));
        assert!(!constant_time_eq(b"secret", b"secreT"));
        assert!(!constant_time_eq(b"secret", b"secret2"));
        assert!(!constant_time_eq(b"", b"x"));
        assert!(constant_time_eq(b"", b""));
    }
}
