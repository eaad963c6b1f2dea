//! The JSON error shape for the answers hyper gives itself, before any handler runs, to
//! requests that are not valid HTTP/1.1: `414` (a request line over its buffer), `431`
//! (headers too large) and `400` (a malformed or repeated header: two `Content-Length`).
//! hyper writes those with an empty body and closes the connection, and offers no hook
//! to shape them; so this IO wrapper on every connection recognises hyper's own answer
//! (status 4xx, then exactly `connection: close` and `content-length: 0`, which no
//! handler of ours writes: every error of ours has a body) and writes the same status
//! with service-api.md's error body instead.

use super::error_code::ErrorCode;
use std::io::{self, IoSlice};
use std::pin::Pin;
use std::task::{Context, Poll};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// How hyper's own error answers begin after their status line.
const HYPER_ERROR_HEADERS: &[u8] = b"\r\nconnection: close\r\ncontent-length: 0\r\n";

/// Wraps a connection's IO; see the module's documentation.
pub struct JsonParseErrors<T> {
    inner: T,
    /// An answer being rewritten: its new bytes, how many are written, and how many
    /// bytes of hyper's answer they stand for.
    rewriting: Option<(Vec<u8>, usize, usize)>,
}

impl<T> JsonParseErrors<T> {
    pub fn new(inner: T) -> Self {
        Self {
            inner,
            rewriting: None,
        }
    }
}

/// hyper's empty answer at the start of `buf`, rewritten with a JSON body: the new bytes
/// and the length of the answer they replace; `None` for anything else.
#[must_use]
pub fn rewrite(buf: &[u8]) -> Option<(Vec<u8>, usize)> {
    let status_line_end = buf.windows(2).position(|w| w == b"\r\n")?;
    let status_line = std::str::from_utf8(&buf[..status_line_end]).ok()?;
    let status: u16 = status_line
        .strip_prefix("HTTP/1.1 ")?
        .get(..3)?
        .parse()
        .ok()?;
    let rest = &buf[status_line_end..];
    if !rest.starts_with(HYPER_ERROR_HEADERS) {
        return None;
    }
    let head_end = buf.windows(4).position(|w| w == b"\r\n\r\n")? + 4;
    let (code, message) = match status {
        400 => (
            ErrorCode::InvalidRequest,
            "the request is not valid HTTP/1.1 (a malformed header, or one such as \
             Content-Length repeated)",
        ),
        414 => (
            ErrorCode::TooLarge,
            "the request line is longer than the server accepts; ids and query values are short",
        ),
        431 => (
            ErrorCode::TooLarge,
            "the request headers are larger than the server accepts",
        ),
        _ => return None,
    };
    let body = serde_json::json!({
        "error": { "code": code, "message": message, "path": "" }
    })
    .to_string();
    // Status line, then hyper's other headers (its `date`) after the two it wrote.
    let others = &buf[status_line_end + HYPER_ERROR_HEADERS.len()..head_end - 2];
    let mut out = Vec::with_capacity(head_end + body.len() + 64);
    out.extend_from_slice(&buf[..status_line_end]);
    out.extend_from_slice(b"\r\nconnection: close\r\ncontent-type: application/json\r\n");
    out.extend_from_slice(format!("content-length: {}\r\n", body.len()).as_bytes());
    out.extend_from_slice(others);
    out.extend_from_slice(b"\r\n");
    out.extend_from_slice(body.as_bytes());
    Some((out, head_end))
}

impl<T: AsyncRead + Unpin> AsyncRead for JsonParseErrors<T> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for JsonParseErrors<T> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = &mut *self;
        if this.rewriting.is_none() && buf.starts_with(b"HTTP/1.1 4") {
            this.rewriting = rewrite(buf).map(|(bytes, replaced)| (bytes, 0, replaced));
        }
        let Some((bytes, written, replaced)) = &mut this.rewriting else {
            return Pin::new(&mut this.inner).poll_write(cx, buf);
        };
        // hyper offers the same bytes again after a `Pending`: the rewrite goes on from
        // where it stopped, and reports hyper's answer written only once all of it is.
        while *written < bytes.len() {
            match Pin::new(&mut this.inner).poll_write(cx, &bytes[*written..]) {
                Poll::Ready(Ok(0)) => return Poll::Ready(Err(io::ErrorKind::WriteZero.into())),
                Poll::Ready(Ok(n)) => *written += n,
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                Poll::Pending => return Poll::Pending,
            }
        }
        let replaced = *replaced;
        this.rewriting = None;
        Poll::Ready(Ok(replaced))
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let first = bufs.iter().find(|b| !b.is_empty());
        if self.rewriting.is_some() || first.is_some_and(|b| b.starts_with(b"HTTP/1.1 4")) {
            return self.poll_write(cx, first.map_or(&[][..], |b| &b[..]));
        }
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::rewrite;

    #[test]
    fn hypers_own_answers_get_the_error_body_and_others_pass() {
        let hyper = b"HTTP/1.1 414 URI Too Long\r\nconnection: close\r\ncontent-length: 0\r\n\
                      date: Tue, 01 Dec 2026 23:30:43 GMT\r\n\r\n";
        let (out, replaced) = rewrite(hyper).unwrap();
        assert_eq!(replaced, hyper.len());
        let text = String::from_utf8(out).unwrap();
        let (head, body) = text.split_once("\r\n\r\n").unwrap();
        assert!(head.starts_with("HTTP/1.1 414 URI Too Long\r\n"), "{head}");
        assert!(
            head.contains("\r\ncontent-type: application/json\r\n"),
            "{head}"
        );
        assert!(
            head.contains(&format!("\r\ncontent-length: {}\r\n", body.len())),
            "{head}"
        );
        assert!(
            head.ends_with("date: Tue, 01 Dec 2026 23:30:43 GMT"),
            "{head}"
        );
        let v: serde_json::Value = serde_json::from_str(body).unwrap();
        assert_eq!(v["error"]["code"], "too_large");

        let dup = b"HTTP/1.1 400 Bad Request\r\nconnection: close\r\ncontent-length: 0\r\n\r\n";
        let (out, _) = rewrite(dup).unwrap();
        assert!(String::from_utf8(out)
            .unwrap()
            .contains("\"invalid_request\""));

        // Our own answers (with a body) and hyper's other ones are left alone.
        let ours = b"HTTP/1.1 400 Bad Request\r\ncontent-type: application/json\r\n\
                     content-length: 2\r\n\r\n{}";
        assert!(rewrite(ours).is_none());
        let ok = b"HTTP/1.1 200 OK\r\nconnection: close\r\ncontent-length: 0\r\n\r\n";
        assert!(rewrite(ok).is_none());
        assert!(rewrite(b"HTTP/1.1 4").is_none());
    }
}
