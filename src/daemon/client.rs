//! A small HTTP/1.1 client for talking to a daemon (`rig collect --daemon URL`, the tests):
//! one request per connection (`Connection: close`), plain HTTP only, bodies framed by
//! `Content-Length`, chunked encoding or the end of the connection. Every request that is not
//! a `GET` or `HEAD` carries `X-Rig-Client: rig` (the daemon's CSRF rule), and a body goes as
//! `Content-Type: application/json`.

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Longest wait for one request's answer.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(30);

/// Errors talking to a daemon.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("daemon URL {url:?}: {reason}")]
    BadUrl { url: String, reason: &'static str },
    #[error("connecting to the daemon at {addr}")]
    Connect {
        addr: String,
        #[source]
        source: std::io::Error,
    },
    #[error("talking to the daemon at {addr}")]
    Io {
        addr: String,
        #[source]
        source: std::io::Error,
    },
    #[error("the daemon at {addr} did not answer within {timeout_s} s")]
    Timeout { addr: String, timeout_s: u64 },
    #[error("the daemon at {addr} sent a malformed HTTP response: {reason}")]
    Malformed { addr: String, reason: &'static str },
    #[error("the daemon answered {status}: {message}")]
    Status { status: u16, message: String },
    #[error("the daemon's answer is not the JSON expected: {source}")]
    Json {
        #[source]
        source: serde_json::Error,
    },
}

/// An HTTP response.
#[derive(Debug, Clone)]
pub struct HttpResponse {
    pub status: u16,
    /// Header names lower-cased.
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl HttpResponse {
    /// The first header of this (lower-case) name.
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(n, _)| n == name).map(|(_, v)| v.as_str())
    }
}

/// Where a daemon listens, and its token.
#[derive(Debug, Clone)]
pub struct DaemonClient {
    /// `host:port`.
    addr: String,
    token: Option<String>,
}

impl DaemonClient {
    /// A client of the daemon at `url` (`http://host:port`, or just `host:port`).
    pub fn new(url: &str, token: Option<String>) -> Result<Self, ClientError> {
        let bad = |reason| ClientError::BadUrl { url: url.to_string(), reason };
        let rest = if let Some(rest) = url.strip_prefix("http://") {
            rest
        } else if url.starts_with("https://") {
            return Err(bad("https is not supported: the daemon speaks plain HTTP on loopback; reach a remote one through an SSH tunnel \
                 (ssh -L 7700:127.0.0.1:7700 HOST) and use --daemon http://127.0.0.1:7700"));
        } else if url.contains("://") {
            return Err(bad("only http:// URLs are supported"));
        } else {
            url
        };
        let authority = rest.split('/').next().unwrap_or_default();
        if authority.is_empty() {
            return Err(bad("no host:port"));
        }
        let addr = if authority.rsplit_once(':').is_some_and(|(_, p)| p.parse::<u16>().is_ok()) && !authority.ends_with(']') {
            authority.to_string()
        } else {
            format!("{authority}:80")
        };
        Ok(Self { addr, token: token.filter(|t| !t.is_empty()) })
    }

    /// `host:port` it talks to.
    pub fn addr(&self) -> &str {
        &self.addr
    }

    /// Sends one request; any status comes back as a response.
    pub async fn request(&self, method: &str, path: &str, json_body: Option<&[u8]>) -> Result<HttpResponse, ClientError> {
        let addr = self.addr.clone();
        match tokio::time::timeout(REQUEST_TIMEOUT, self.exchange(method, path, json_body)).await {
            Ok(r) => r,
            Err(_) => Err(ClientError::Timeout { addr, timeout_s: REQUEST_TIMEOUT.as_secs() }),
        }
    }

    async fn exchange(&self, method: &str, path: &str, json_body: Option<&[u8]>) -> Result<HttpResponse, ClientError> {
        let mut stream = TcpStream::connect(&self.addr).await.map_err(|source| ClientError::Connect { addr: self.addr.clone(), source })?;
        let io = |source| ClientError::Io { addr: self.addr.clone(), source };
        let mut head = format!("{method} {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n", self.addr);
        if let Some(token) = &self.token {
            head.push_str(&format!("Authorization: Bearer {token}\r\n"));
        }
        let body = json_body.unwrap_or_default();
        if json_body.is_some() {
            head.push_str("Content-Type: application/json\r\n");
        }
        if !matches!(method, "GET" | "HEAD") {
            head.push_str("X-Rig-Client: rig\r\n");
        }
        head.push_str(&format!("Content-Length: {}\r\n\r\n", body.len()));
        stream.write_all(head.as_bytes()).await.map_err(io)?;
        stream.write_all(body).await.map_err(io)?;
        let mut raw = Vec::new();
        stream.read_to_end(&mut raw).await.map_err(io)?;
        parse_response(&raw).map_err(|reason| ClientError::Malformed { addr: self.addr.clone(), reason })
    }

    /// GET `path`, JSON answer; a status other than 2xx is an error carrying the daemon's message.
    pub async fn get_json<T: serde::de::DeserializeOwned>(&self, path: &str) -> Result<T, ClientError> {
        json_of(self.request("GET", path, None).await?)
    }

    /// POST `body` (JSON) to `path`, JSON answer.
    pub async fn post_json<T: serde::de::DeserializeOwned>(&self, path: &str, body: &serde_json::Value) -> Result<T, ClientError> {
        let bytes = serde_json::to_vec(body).map_err(|source| ClientError::Json { source })?;
        json_of(self.request("POST", path, Some(&bytes)).await?)
    }
}

fn json_of<T: serde::de::DeserializeOwned>(response: HttpResponse) -> Result<T, ClientError> {
    if !(200..300).contains(&response.status) {
        let message = serde_json::from_slice::<serde_json::Value>(&response.body)
            .ok()
            .and_then(|v| v.get("error").and_then(|e| e.as_str()).map(str::to_string))
            .unwrap_or_else(|| String::from_utf8_lossy(&response.body).into_owned());
        return Err(ClientError::Status { status: response.status, message });
    }
    serde_json::from_slice(&response.body).map_err(|source| ClientError::Json { source })
}

/// Parses a whole HTTP/1.1 response (the connection has closed).
pub fn parse_response(raw: &[u8]) -> Result<HttpResponse, &'static str> {
    let end = raw.windows(4).position(|w| w == b"\r\n\r\n").ok_or("no end of headers")?;
    let head = std::str::from_utf8(&raw[..end]).map_err(|_| "headers are not UTF-8")?;
    let mut lines = head.split("\r\n");
    let status_line = lines.next().ok_or("no status line")?;
    let mut parts = status_line.splitn(3, ' ');
    if !parts.next().is_some_and(|v| v.starts_with("HTTP/1.")) {
        return Err("not an HTTP/1 status line");
    }
    let status: u16 = parts.next().and_then(|s| s.parse().ok()).ok_or("bad status code")?;
    let mut headers = Vec::new();
    for line in lines {
        let (name, value) = line.split_once(':').ok_or("header line without a colon")?;
        headers.push((name.trim().to_ascii_lowercase(), value.trim().to_string()));
    }
    let rest = &raw[end + 4..];
    let find = |name: &str| headers.iter().find(|(n, _)| n == name).map(|(_, v)| v.as_str());
    let body = if find("transfer-encoding").is_some_and(|v| v.eq_ignore_ascii_case("chunked")) {
        dechunk(rest)?
    } else if let Some(len) = find("content-length") {
        let len: usize = len.parse().map_err(|_| "bad Content-Length")?;
        rest.get(..len).ok_or("body shorter than its Content-Length")?.to_vec()
    } else {
        rest.to_vec()
    };
    Ok(HttpResponse { status, headers, body })
}

fn dechunk(mut rest: &[u8]) -> Result<Vec<u8>, &'static str> {
    let mut body = Vec::new();
    loop {
        let line_end = rest.windows(2).position(|w| w == b"\r\n").ok_or("chunk size line without an end")?;
        let size_text = std::str::from_utf8(&rest[..line_end]).map_err(|_| "chunk size is not text")?;
        let size_text = size_text.split(';').next().unwrap_or_default().trim();
        let size = usize::from_str_radix(size_text, 16).map_err(|_| "bad chunk size")?;
        rest = &rest[line_end + 2..];
        if size == 0 {
            return Ok(body);
        }
        body.extend_from_slice(rest.get(..size).ok_or("chunk shorter than its size")?);
        rest = rest.get(size + 2..).ok_or("chunk without its line end")?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_length_chunked_and_close_framed_bodies() {
        let r = parse_response(b"HTTP/1.1 200 OK\r\ncontent-length: 2\r\n\r\nhiXX").unwrap();
        assert_eq!((r.status, r.body.as_slice()), (200, b"hi".as_slice()));
        let r = parse_response(b"HTTP/1.1 201 Created\r\nTransfer-Encoding: chunked\r\n\r\n3\r\nabc\r\n2\r\nde\r\n0\r\n\r\n").unwrap();
        assert_eq!((r.status, r.body.as_slice()), (201, b"abcde".as_slice()));
        let r = parse_response(b"HTTP/1.0 404 Not Found\r\nX: y\r\n\r\nrest").unwrap();
        assert_eq!((r.status, r.body.as_slice(), r.header("x")), (404, b"rest".as_slice(), Some("y")));
    }

    #[test]
    fn malformed_responses_are_errors_not_panics() {
        for raw in [
            &b""[..],
            b"HTTP/1.1 200",
            b"garbage\r\n\r\n",
            b"HTTP/1.1 abc OK\r\n\r\n",
            b"HTTP/1.1 200 OK\r\ncontent-length: 9\r\n\r\nab",
            b"HTTP/1.1 200 OK\r\ntransfer-encoding: chunked\r\n\r\nzz\r\n",
            b"HTTP/1.1 200 OK\r\ntransfer-encoding: chunked\r\n\r\n5\r\nab",
        ] {
            assert!(parse_response(raw).is_err(), "{:?}", String::from_utf8_lossy(raw));
        }
    }

    #[test]
    fn urls() {
        assert_eq!(DaemonClient::new("http://127.0.0.1:7700", None).unwrap().addr(), "127.0.0.1:7700");
        assert_eq!(DaemonClient::new("localhost:9/x", None).unwrap().addr(), "localhost:9");
        assert_eq!(DaemonClient::new("http://rig.lab", None).unwrap().addr(), "rig.lab:80");
        assert!(DaemonClient::new("https://rig.lab", None).is_err());
        assert!(DaemonClient::new("http://", None).is_err());
    }
}
