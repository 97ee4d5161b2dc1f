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
//!
//! A slowloris (a head sent a byte at a time, or never finished) holds one connection for
//! [`HEADER_TIMEOUT`] at most, and thousands of them hold at most [`MAX_CONNECTIONS`].

use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::AsyncWriteExt;
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
/// How long a stop waits for open connections to finish their request.
const STOP_GRACE: Duration = Duration::from_secs(5);

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
            let connection = builder.serve_connection(TokioIo::new(stream), service);
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
