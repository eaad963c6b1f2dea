//! Access control for `/v1` (issue #5): off by default; with a token, every `/v1` call
//! needs `Authorization: Bearer <token>`. WebSocket streams may pass `?token=` instead,
//! because browsers cannot set headers on a WebSocket. `/`, `/healthz` and `/metrics`
//! stay open (the viewer page asks for the token itself; probes need no secret).

use super::http::{ApiError, AppState, ErrorCode};
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
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(str::trim);
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
    use super::constant_time_eq;

    #[test]
    fn compares_bytes_exactly() {
        assert!(constant_time_eq(b"secret", b"secret"));
        assert!(!constant_time_eq(b"secret", b"secreT"));
        assert!(!constant_time_eq(b"secret", b"secret2"));
        assert!(!constant_time_eq(b"", b"x"));
        assert!(constant_time_eq(b"", b""));
    }
}
