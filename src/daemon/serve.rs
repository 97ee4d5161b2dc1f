//! The daemon's HTTP/1.1 server loop: hyper connections with a header-read timeout that also
//! ends idle keep-alive connections, a cap on open connections, and a graceful stop.
//!
//! | limit | value | what happens past it |
//! |---|---|---|
//! | request head (line and headers) | [`HEADER_TIMEOUT`] from the first wait for it | the connection is closed |
//! | idle keep-alive connection | [`HEADER_TIMEOUT`] (hyper arms the same timer while waiting for the next request) | the connection is closed |
//! | request head size | [`MAX_HEAD_BYTES`], at most [`MAX_HEADERS`] headers | hyper answers 431 and closes |
//! | request body | [`super::api::MAX_BODY_BYTES`] within [`super::api::BODY_TIMEOUT`] | 413 or 408 (JSON) |
//! | open connections | [`MAX_CONNECTIONS`] | a new one gets a JSON 503 and is closed |
//! | a response write (or flush) that makes no progress | [`WRITE_TIMEOUT`] | the connection is closed |
//!
//! A slowloris (a head sent a byte at a time, or never finished) holds one connection for
//! [`HEADER_TIMEOUT`] at most, and thousands of them hold at most [`MAX_CONNECTIONS`]. A
//! client that asks and never reads holds one for [`WRITE_TIMEOUT`] once its socket buffers
//! are full (`ConnIo`).
//!
//! hyper answers a request it cannot parse itself, before any handler runs (400 for a bad
//! request line or header, 414 for a long target, 431 for a head over [`MAX_HEAD_BYTES`]),
//! with an empty body; `ConnIo` rewrites those answers as the JSON `{"error": "..."}` every
//! other error has.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::net::TcpListener;
use tokio::sync::{Semaphore, watch};
use tokio::task::JoinSet;

/// Longest wait for a request's head, and for the next request on a kept-alive connection.
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(10);
/// Largest request head hyper buffers.
pub const MAX_HEAD_BYTES: usize = 16 * 1024;
/// Most headers in one request.
pub const MAX_HEADERS: usize = 64;
/// Most connections open at once (the page polls with a few; a lab has a handful of clients).
pub const MAX_CONNECTIONS: usize = 256;
/// Longest a response write may make no progress (a client that stopped reading).
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a stop waits for open connections to finish their request (short: the arm is
/// already safe by then, and SIGTERM must end the daemon within 5 s).
const STOP_GRACE: Duration = Duration::from_millis(500);

/// Serves `router` on `listener` until `stop` turns true, then stops accepting, lets open
/// connections finish the request in flight (at most [`STOP_GRACE`]) and returns.
pub(crate) async fn serve(listener: TcpListener, router: Router, mut stop: watch::Receiver<bool>) -> std::io::Result<()> {
    let slots = Arc::new(Semaphore::new(MAX_CONNECTIONS));
    let mut connections = JoinSet::new();
    loop {
        let accepted = tokio::select! {
            () = stopped(&mut stop) => break,
            accepted = listener.accept() => accepted,
            // Reap finished connection tasks as they end, so the set does not grow.
            Some(_) = connections.join_next(), if !connections.is_empty() => continue,
        };
        let stream = match accepted {
            Ok((stream, _)) => stream,
            Err(e) => {
                // Out of file descriptors and the like: wait instead of spinning.
                tracing::warn!(error = %e, "accepting a connection");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let Ok(slot) = Arc::clone(&slots).try_acquire_owned() else {
            connections.spawn(refuse_busy(stream));
            continue;
        };
        let service = TowerToHyperService::new(router.clone());
        let mut stop = stop.clone();
        connections.spawn(async move {
            let mut builder = hyper::server::conn::http1::Builder::new();
            builder
                .timer(TokioTimer::new())
                .header_read_timeout(HEADER_TIMEOUT)
                .keep_alive(true)
                .max_buf_size(MAX_HEAD_BYTES)
                .max_headers(MAX_HEADERS);
            let connection = builder.serve_connection(TokioIo::new(ConnIo::new(stream)), service);
            tokio::pin!(connection);
            tokio::select! {
                _ = connection.as_mut() => {}
                () = stopped(&mut stop) => {
                    connection.as_mut().graceful_shutdown();
                    let _ = connection.await;
                }
            }
            drop(slot);
        });
    }
    drop(listener);
    if tokio::time::timeout(STOP_GRACE, async { while connections.join_next().await.is_some() {} }).await.is_err() {
        connections.abort_all();
    }
    Ok(())
}

/// Resolves once `stop` is true (or its sender is gone), holding no borrow of it.
async fn stopped(stop: &mut watch::Receiver<bool>) {
    let _ = stop.wait_for(|s| *s).await;
}

/// Answers a connection over the cap with a JSON 503 and closes it.
async fn refuse_busy(mut stream: tokio::net::TcpStream) {
    let body = format!(r#"{{"error":"the daemon has {MAX_CONNECTIONS} connections open; try again"}}"#);
    let response = format!(
        "HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\ncontent-length: {}\r\nconnection: close\r\n\r\n{body}",
        body.len()
    );
    let _ = tokio::time::timeout(Duration::from_secs(1), stream.write_all(response.as_bytes())).await;
    let _ = stream.shutdown().await;
}

/// A connection's socket as hyper sees it: reads pass through; a write or flush that stays
/// pending for [`WRITE_TIMEOUT`] fails with `TimedOut` (hyper then closes the connection), and
/// hyper's own empty-bodied parse-error answers are replaced by JSON ones ([`json_for_parse_error`]).
pub(crate) struct ConnIo<S> {
    inner: S,
    /// Armed when a write or flush first returns pending; cleared on progress.
    stalled: Option<Pin<Box<tokio::time::Sleep>>>,
    /// [`WRITE_TIMEOUT`], but for tests.
    timeout: Duration,
    /// A replacement answer being written, and how much of it is written.
    replacement: Option<(Vec<u8>, usize)>,
}

impl<S> ConnIo<S> {
    pub(crate) fn new(inner: S) -> Self {
        Self::with_timeout(inner, WRITE_TIMEOUT)
    }

    fn with_timeout(inner: S, timeout: Duration) -> Self {
        Self { inner, stalled: None, timeout, replacement: None }
    }
}

/// `poll` with the write deadline: progress clears it, a pending result arms it, and a pending
/// result past it is a `TimedOut` error.
fn timed<T>(
    stalled: &mut Option<Pin<Box<tokio::time::Sleep>>>,
    timeout: Duration,
    cx: &mut Context<'_>,
    poll: Poll<io::Result<T>>,
) -> Poll<io::Result<T>> {
    match poll {
        Poll::Ready(result) => {
            *stalled = None;
            Poll::Ready(result)
        }
        Poll::Pending => {
            let sleep = stalled.get_or_insert_with(|| Box::pin(tokio::time::sleep(timeout)));
            match sleep.as_mut().poll(cx) {
                Poll::Ready(()) => Poll::Ready(Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!("the client read nothing of the response for {timeout:?}"),
                ))),
                Poll::Pending => Poll::Pending,
            }
        }
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for ConnIo<S> {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_read(cx, buf)
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for ConnIo<S> {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        if this.replacement.is_none()
            && let Some(json) = json_for_parse_error(buf)
        {
            this.replacement = Some((json, 0));
        }
        if let Some((bytes, written)) = &mut this.replacement {
            // hyper is told its whole buffer went out once the replacement has.
            while *written < bytes.len() {
                let poll = Pin::new(&mut this.inner).poll_write(cx, &bytes[*written..]);
                match timed(&mut this.stalled, this.timeout, cx, poll) {
                    Poll::Ready(Ok(0)) => return Poll::Ready(Err(io::ErrorKind::WriteZero.into())),
                    Poll::Ready(Ok(n)) => *written += n,
                    Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                    Poll::Pending => return Poll::Pending,
                }
            }
            this.replacement = None;
            return Poll::Ready(Ok(buf.len()));
        }
        let poll = Pin::new(&mut this.inner).poll_write(cx, buf);
        timed(&mut this.stalled, this.timeout, cx, poll)
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let poll = Pin::new(&mut this.inner).poll_flush(cx);
        timed(&mut this.stalled, this.timeout, cx, poll)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let poll = Pin::new(&mut this.inner).poll_shutdown(cx);
        timed(&mut this.stalled, this.timeout, cx, poll)
    }
}

/// The JSON answer for one of hyper's automatic parse-error answers (`buf` starting with its
/// status line, holding `content-length: 0` and ending with the head), else `None`. The
/// daemon's own handlers never answer 400, 414 or 431 without a JSON body, so only hyper's
/// match.
pub(crate) fn json_for_parse_error(buf: &[u8]) -> Option<Vec<u8>> {
    let head = std::str::from_utf8(buf).ok()?;
    let rest = head.strip_prefix("HTTP/1.1 ").or_else(|| head.strip_prefix("HTTP/1.0 "))?;
    if !head.ends_with("\r\n\r\n") || !head.to_ascii_lowercase().contains("\r\ncontent-length: 0\r\n") {
        return None;
    }
    let (status, message) = match rest.get(..4)? {
        "400 " => ("400 Bad Request", "the request is not valid HTTP/1.1: its request line or a header could not be parsed".to_string()),
        "414 " => ("414 URI Too Long", "the request target is longer than the daemon reads".to_string()),
        "431 " => (
            "431 Request Header Fields Too Large",
            format!("the request head is larger than the {MAX_HEAD_BYTES} bytes or {MAX_HEADERS} headers the daemon reads"),
        ),
        _ => return None,
    };
    let body = serde_json::json!({ "error": message }).to_string();
    Some(
        format!("HTTP/1.1 {status}\r\ncontent-type: application/json\r\ncontent-length: {}\r\nconnection: close\r\n\r\n{body}", body.len())
            .into_bytes(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_hypers_empty_parse_error_answers_are_rewritten() {
        let hyper_431 = b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-length: 0\r\ndate: Thu, 26 Nov 2026 00:00:00 GMT\r\n\r\n";
        let json = String::from_utf8(json_for_parse_error(hyper_431).expect("rewritten")).expect("utf-8");
        assert!(json.starts_with("HTTP/1.1 431 ") && json.contains("content-type: application/json"), "{json}");
        let body: serde_json::Value = serde_json::from_str(json.split("\r\n\r\n").nth(1).expect("body")).expect("JSON body");
        assert!(body["error"].as_str().is_some_and(|e| e.contains("16384 bytes")), "{body}");
        let hyper_400 = b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n";
        assert!(json_for_parse_error(hyper_400).is_some());
        // A handler's JSON 400, a 200 with an empty body and a partial head are left alone.
        for other in [
            &b"HTTP/1.1 400 Bad Request\r\ncontent-type: application/json\r\ncontent-length: 12\r\n\r\n{\"error\":\"\"}"[..],
            b"HTTP/1.1 200 OK\r\ncontent-length: 0\r\n\r\n",
            b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-length: 0\r\n",
            b"\xff\xfe",
        ] {
            assert!(json_for_parse_error(other).is_none(), "{:?}", String::from_utf8_lossy(other));
        }
    }

    #[tokio::test]
    async fn a_write_the_peer_never_reads_times_out() {
        // A 64 KiB pipe whose other end is never read.
        let (ours, _theirs) = tokio::io::duplex(64 * 1024);
        let mut io = ConnIo::with_timeout(ours, Duration::from_millis(200));
        let chunk = vec![0u8; 1 << 20];
        let e = io.write_all(&chunk).await.expect_err("the peer reads nothing");
        assert_eq!(e.kind(), io::ErrorKind::TimedOut, "{e}");
    }
}
