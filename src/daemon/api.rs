//! The HTTP API (axum over the daemon's tokio runtime) and the page.
//!
//! | method and path | answer |
//! |---|---|
//! | `GET /` | the live page (HTML; it polls the API below) |
//! | `GET /api/status` | [`StatusView`](super::state::StatusView) |
//! | `GET /api/jobs?limit=N&before=ID` | a page of [`JobView`](super::state::JobView)s, oldest first: the newest `N` (default and at most [`MAX_PAGE`](super::state::MAX_PAGE)) with an id below `ID` (any, without it); headers `x-rig-jobs-total` and, when older jobs remain, `x-rig-next-before` (the `before` of the next page) |
//! | `POST /api/jobs` | queue a [`JobRequest`] (JSON body); 201 with the job |
//! | `GET /api/jobs/{id}` | one job |
//! | `POST /api/jobs/{id}/cancel`, `DELETE /api/jobs/{id}` | cancel it (a running job stops at its next safe point) |
//! | `GET /api/frames/{sensor}` | the sensor's latest frame (JPEG) |
//! | `GET /api/synth/latest/{control\|image}` | the latest control or synthetic image of a synth job (PNG) |
//!
//! Every request passes [`guard`] first, in this order:
//!
//! 1. **Host** ([`HostRule`]): a request carries exactly one `Host` header (none or two: 400)
//!    and its target is a path, never an absolute URL (400); the `Host` header's name (its
//!    port is ignored) must be `localhost`, a loopback IP, the IP the daemon listens on (any IP
//!    literal when it listens on `0.0.0.0` or `[::]`), or a name given with `--allow-host`;
//!    otherwise 403. A page on another site that rebinds its DNS name to 127.0.0.1 sends its
//!    own name: refused.
//! 2. **State-changing requests** (any method but `GET` and `HEAD`) must carry the daemon's
//!    token (`Authorization: Bearer`) or an `X-Rig-Client` header (any value), 403 otherwise;
//!    an `Origin` header, when present, must name an allowed host too; a body must be
//!    `Content-Type: application/json` (415 otherwise). A browser cannot send a custom header
//!    or a JSON content type to another origin without a CORS preflight, which the daemon
//!    answers 405 with no `Access-Control-Allow-*` headers: so a page on another origin cannot
//!    queue or cancel a job, with or without a token.
//! 3. **Body**: at most [`MAX_BODY_BYTES`]; a larger `Content-Length` is refused (413) before
//!    a byte of it is read, and the whole body must arrive within [`BODY_TIMEOUT`] (408).
//!
//! With a token, every `/api/` request must also carry `Authorization: Bearer <token>` (401
//! otherwise); the page itself is served without it and sends the token it was given in its
//! URL fragment (`/#token=...`, which browsers do not send to the server). Every error is JSON
//! `{"error": "..."}`, whatever its status (400, 401, 403, 404, 405, 408, 409, 413, 414, 415, 431,
//! 503): [`json_errors`] rewrites any other error body, and [`super::serve`] the answers hyper
//! gives a request it cannot parse. Header and idle timeouts and the connection
//! cap are in [`super::serve`].

use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::{Body, Bytes};
use axum::extract::{Path, Request, State};
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::{get, post};
use serde_json::json;

use super::state::{CancelError, DaemonState};
use crate::jobs::JobRequest;
use crate::roots::DataRoots;

/// The page, one self-contained file.
pub const PAGE_HTML: &str = include_str!("page.html");

/// Largest request body (a job is a few hundred bytes of JSON).
pub const MAX_BODY_BYTES: usize = 64 * 1024;
/// Longest a request body may take to arrive.
pub const BODY_TIMEOUT: Duration = Duration::from_secs(10);
/// The header a client other than a browser page of another origin sends on state-changing
/// requests when it has no token (rig's own client and page send it).
pub const CLIENT_HEADER: &str = "x-rig-client";

/// Which `Host` (and `Origin`) names the daemon answers to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HostRule {
    /// Where the daemon listens.
    pub listen: SocketAddr,
    /// Names given with `--allow-host` (lower case, no port).
    pub names: Vec<String>,
}

impl HostRule {
    /// The rule for a daemon listening on `listen` that also answers to `names`.
    pub fn new(listen: SocketAddr, names: &[String]) -> Self {
        Self { listen, names: names.iter().map(|n| n.trim().trim_end_matches('.').to_ascii_lowercase()).collect() }
    }

    /// Whether a `Host` header value (`name`, `name:port`, `[v6]:port`) is allowed.
    pub fn allows(&self, host: &str) -> bool {
        let Some(name) = host_name(host) else { return false };
        if name == "localhost" || self.names.contains(&name) {
            return true;
        }
        match name.trim_start_matches('[').trim_end_matches(']').parse::<IpAddr>() {
            Ok(ip) => ip.is_loopback() || ip == self.listen.ip() || self.listen.ip().is_unspecified(),
            Err(_) => false,
        }
    }
}

/// The name part of a `Host` value, lower case, without the port and a trailing dot; `None`
/// when it is malformed.
fn host_name(host: &str) -> Option<String> {
    let host = host.trim();
    if host.is_empty() || host.len() > 255 || host.contains(['/', '@', ' ']) {
        return None;
    }
    let name = if let Some(rest) = host.strip_prefix('[') {
        let end = rest.find(']')?;
        let after = &rest[end + 1..];
        if !(after.is_empty() || after.strip_prefix(':').is_some_and(|p| p.parse::<u16>().is_ok())) {
            return None;
        }
        format!("[{}]", &rest[..end])
    } else {
        match host.rsplit_once(':') {
            Some((name, port)) if port.parse::<u16>().is_ok() && !name.contains(':') => name.to_string(),
            Some(_) => return None,
            None => host.to_string(),
        }
    };
    Some(name.trim_end_matches('.').to_ascii_lowercase())
}

/// What every handler gets.
#[derive(Clone)]
pub struct ApiState {
    pub state: Arc<DaemonState>,
    /// `None`: no token needed (loopback only).
    pub token: Option<Arc<str>>,
    /// Which `Host` names are answered.
    pub hosts: Arc<HostRule>,
    /// The folders a job's paths must resolve inside.
    pub roots: Arc<DataRoots>,
}

/// The daemon's routes.
pub fn router(api: ApiState) -> Router {
    let routes = Router::new()
        .route("/api/status", get(status))
        .route("/api/jobs", get(list_jobs).post(submit_job))
        .route("/api/jobs/{id}", get(get_job).delete(cancel_job))
        .route("/api/jobs/{id}/cancel", post(cancel_job))
        .route("/api/frames/{sensor}", get(frame))
        .route("/api/synth/latest/{which}", get(synth_latest))
        .fallback(not_found)
        .layer(middleware::from_fn_with_state(api.clone(), require_token));
    routes
        .route("/", get(page))
        .layer(middleware::from_fn(json_errors))
        .layer(middleware::from_fn_with_state(api.clone(), guard))
        .with_state(api)
}

/// A JSON error response.
pub fn error(status: StatusCode, message: impl Into<String>) -> Response {
    (status, axum::Json(json!({ "error": message.into() }))).into_response()
}

/// Constant-time comparison, so the token does not leak through response timing.
fn same_token(given: &[u8], expected: &[u8]) -> bool {
    given.len() == expected.len() && given.iter().zip(expected).fold(0u8, |acc, (a, b)| acc | (a ^ b)) == 0
}

/// The bearer token a request carries, if any.
fn bearer(headers: &HeaderMap) -> Option<&str> {
    headers.get(header::AUTHORIZATION).and_then(|v| v.to_str().ok()).and_then(|v| v.strip_prefix("Bearer ")).map(str::trim)
}

/// The `Host`, CSRF and body rules of the module docs, before any handler runs.
pub async fn guard(State(api): State<ApiState>, request: Request, next: Next) -> Response {
    let headers = request.headers();
    // An absolute-form target (`GET http://evil.example/api/status`) names a host of its own,
    // which a server may take over the Host header: only proxies are sent those, so none is
    // answered.
    if request.uri().scheme().is_some() || request.uri().authority().is_some() {
        return error(StatusCode::BAD_REQUEST, "the request target must be a path (origin form, /api/...), not an absolute URL");
    }
    // Exactly one Host: with two, which one a check reads and which one a proxy or a log
    // believes may differ.
    let mut hosts = headers.get_all(header::HOST).iter();
    let host = match (hosts.next(), hosts.next()) {
        (Some(h), None) => h.to_str().ok(),
        (None, _) => return error(StatusCode::BAD_REQUEST, "the request has no Host header"),
        (Some(_), Some(_)) => return error(StatusCode::BAD_REQUEST, "the request has more than one Host header"),
    };
    if !host.is_some_and(|h| api.hosts.allows(h)) {
        return error(
            StatusCode::FORBIDDEN,
            "the Host header names neither this daemon's address nor a loopback name (start the daemon with --allow-host NAME \
             to answer to another name)",
        );
    }
    let changes_state = !matches!(*request.method(), Method::GET | Method::HEAD);
    if changes_state {
        let with_token = api.token.as_ref().is_some_and(|t| bearer(headers).is_some_and(|g| same_token(g.as_bytes(), t.as_bytes())));
        let with_header = headers.get(CLIENT_HEADER).is_some_and(|v| !v.is_empty());
        if request.method() == Method::OPTIONS {
            // A CORS preflight: no Access-Control-Allow-* headers, so the browser sends nothing.
            return error(StatusCode::METHOD_NOT_ALLOWED, "this daemon does not answer cross-origin requests");
        }
        if !with_token && !with_header {
            return error(
                StatusCode::FORBIDDEN,
                "requests that change state need the X-Rig-Client header or the daemon's token (Authorization: Bearer)",
            );
        }
        if let Some(origin) = headers.get(header::ORIGIN) {
            let allowed = origin.to_str().ok().and_then(|o| o.split_once("://")).is_some_and(|(_, rest)| api.hosts.allows(rest));
            if !allowed {
                return error(StatusCode::FORBIDDEN, "the Origin header names a page this daemon does not answer to");
            }
        }
    }
    let length = headers.get(header::CONTENT_LENGTH).and_then(|v| v.to_str().ok()).map(|v| v.trim().parse::<u64>());
    let chunked = headers.contains_key(header::TRANSFER_ENCODING);
    let has_body = chunked || length.as_ref().is_some_and(|l| !matches!(l, Ok(0)));
    if matches!(length, Some(Err(_))) {
        return error(StatusCode::BAD_REQUEST, "Content-Length is not a number");
    }
    if let Some(Ok(n)) = length
        && n > MAX_BODY_BYTES as u64
    {
        return too_large();
    }
    if !has_body {
        return next.run(request).await;
    }
    if changes_state {
        let json = headers
            .get(header::CONTENT_TYPE)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.split(';').next())
            .is_some_and(|media| media.trim().eq_ignore_ascii_case("application/json"));
        if !json {
            return error(StatusCode::UNSUPPORTED_MEDIA_TYPE, "the body must be JSON (Content-Type: application/json)");
        }
    }
    let (parts, body) = request.into_parts();
    let bytes = match tokio::time::timeout(BODY_TIMEOUT, axum::body::to_bytes(body, MAX_BODY_BYTES)).await {
        Ok(Ok(bytes)) => bytes,
        Ok(Err(_)) => return too_large(),
        Err(_) => return error(StatusCode::REQUEST_TIMEOUT, format!("the body did not arrive within {} s", BODY_TIMEOUT.as_secs())),
    };
    next.run(Request::from_parts(parts, Body::from(bytes))).await
}

fn too_large() -> Response {
    let mut response = error(StatusCode::PAYLOAD_TOO_LARGE, format!("the body is larger than the {MAX_BODY_BYTES} bytes a request may be"));
    // The rest of the body is not read: the connection cannot carry another request.
    response.headers_mut().insert(header::CONNECTION, HeaderValue::from_static("close"));
    response
}

/// Rewrites an error response whose body is not JSON (axum's own 405, 413, 415, 400...) as
/// `{"error": "..."}` with the same status.
pub async fn json_errors(request: Request, next: Next) -> Response {
    let method = request.method().clone();
    let path = request.uri().path().to_string();
    let response = next.run(request).await;
    let status = response.status();
    let is_json = response.headers().get(header::CONTENT_TYPE).is_some_and(|v| v.as_bytes().starts_with(b"application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return response;
    }
    let (parts, body) = response.into_parts();
    let text = axum::body::to_bytes(body, 4096).await.ok().map(|b| String::from_utf8_lossy(&b).trim().to_string()).unwrap_or_default();
    let reason = status.canonical_reason().unwrap_or("error").to_ascii_lowercase();
    let message = match (status, text.is_empty()) {
        (StatusCode::METHOD_NOT_ALLOWED, _) => format!("{method} is not allowed on {path}"),
        (_, true) => reason,
        (_, false) => format!("{reason}: {text}"),
    };
    let mut rewritten = error(status, message);
    for name in [header::ALLOW, header::CONNECTION] {
        if let Some(v) = parts.headers.get(&name) {
            rewritten.headers_mut().insert(name, v.clone());
        }
    }
    rewritten
}

async fn require_token(State(api): State<ApiState>, request: Request, next: Next) -> Response {
    if let Some(token) = &api.token {
        match bearer(request.headers()) {
            Some(given) if same_token(given.as_bytes(), token.as_bytes()) => {}
            Some(_) => return error(StatusCode::UNAUTHORIZED, "wrong token"),
            None => {
                return error(StatusCode::UNAUTHORIZED, "this daemon needs `Authorization: Bearer <token>` (its --token)");
            }
        }
    }
    next.run(request).await
}

async fn page() -> Html<&'static str> {
    Html(PAGE_HTML)
}

async fn not_found(request: Request) -> Response {
    error(StatusCode::NOT_FOUND, format!("no route {} {}", request.method(), request.uri().path()))
}

async fn status(State(api): State<ApiState>) -> Response {
    axum::Json(api.state.status()).into_response()
}

async fn list_jobs(State(api): State<ApiState>, uri: axum::http::Uri) -> Response {
    let mut before = None;
    let mut limit = super::state::MAX_PAGE;
    for pair in uri.query().unwrap_or_default().split('&').filter(|p| !p.is_empty()) {
        let (key, value) = pair.split_once('=').unwrap_or((pair, ""));
        let number = value.parse::<u64>();
        match (key, number) {
            ("before", Ok(id)) => before = Some(id),
            ("limit", Ok(n)) if n >= 1 => limit = usize::try_from(n).unwrap_or(usize::MAX).min(super::state::MAX_PAGE),
            ("before" | "limit", _) => {
                return error(
                    StatusCode::BAD_REQUEST,
                    format!("{key} must be a positive whole number (limit: 1 to {})", super::state::MAX_PAGE),
                );
            }
            _ => return error(StatusCode::BAD_REQUEST, "GET /api/jobs takes limit=N and before=ID only"),
        }
    }
    let page = api.state.jobs_page(before, limit);
    let mut response = axum::Json(page.jobs).into_response();
    let headers = response.headers_mut();
    headers.insert("x-rig-jobs-total", HeaderValue::from(page.total));
    if let Some(next) = page.next_before {
        headers.insert("x-rig-next-before", HeaderValue::from(next));
    }
    response
}

fn bad_id(text: &str) -> Response {
    error(StatusCode::BAD_REQUEST, format!("job id {text:?} is not a number"))
}

async fn get_job(State(api): State<ApiState>, Path(id): Path<String>) -> Response {
    let Ok(id) = id.parse::<u64>() else { return bad_id(&id) };
    match api.state.job(id) {
        Some(job) => axum::Json(job).into_response(),
        None => error(StatusCode::NOT_FOUND, format!("no job {id}")),
    }
}

async fn submit_job(State(api): State<ApiState>, headers: HeaderMap, body: Bytes) -> Response {
    // The guard has checked the media type of any body; an empty body has none.
    if !headers.get(header::CONTENT_TYPE).and_then(|v| v.to_str().ok()).is_some_and(|v| v.starts_with("application/json")) {
        return error(StatusCode::UNSUPPORTED_MEDIA_TYPE, "the body must be JSON (Content-Type: application/json)");
    }
    let mut spec: JobRequest = match serde_json::from_slice(&body) {
        Ok(spec) => spec,
        Err(e) => {
            return error(
                StatusCode::BAD_REQUEST,
                format!(
                    "bad job: {e} (expected {{\"kind\": \"collect\" | \"synth\" | \"calibrate\" | \"audit\", ...the command's options}})"
                ),
            );
        }
    };
    // Numbers within their bounds and every path inside the data roots, before the job is
    // queued: a bad job is refused here (400) and never waits in the queue.
    if let Err(e) = spec.check() {
        return error(StatusCode::BAD_REQUEST, format!("bad job: {e}"));
    }
    if let Err(e) = spec.confine(&api.roots, crate::jobs::Confine::Submitted) {
        return error(StatusCode::BAD_REQUEST, format!("bad job: {e}"));
    }
    match api.state.submit(spec) {
        Ok(job) => (StatusCode::CREATED, axum::Json(job)).into_response(),
        Err(e) => error(StatusCode::SERVICE_UNAVAILABLE, e.to_string()),
    }
}

async fn cancel_job(State(api): State<ApiState>, Path(id): Path<String>) -> Response {
    let Ok(id) = id.parse::<u64>() else { return bad_id(&id) };
    match api.state.cancel(id) {
        Ok(job) => axum::Json(job).into_response(),
        Err(e @ CancelError::NoSuchJob { .. }) => error(StatusCode::NOT_FOUND, e.to_string()),
        Err(e @ CancelError::AlreadyFinal { .. }) => error(StatusCode::CONFLICT, e.to_string()),
    }
}

fn image_response(content_type: &'static str, seq: u64, bytes: Arc<Vec<u8>>) -> Response {
    let mut response = Bytes::from(bytes.as_ref().clone()).into_response();
    let headers = response.headers_mut();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    if let Ok(v) = HeaderValue::from_str(&seq.to_string()) {
        headers.insert("x-rig-seq", v);
    }
    response
}

async fn frame(State(api): State<ApiState>, Path(sensor): Path<String>) -> Response {
    match api.state.frame(&sensor) {
        Some(f) => image_response(f.content_type, f.seq, f.bytes),
        None => {
            let known: Vec<String> = api.state.status().sensors.into_iter().map(|s| s.name).collect();
            error(StatusCode::NOT_FOUND, format!("no frame of sensor {sensor:?} yet (sensors with frames: {known:?})"))
        }
    }
}

async fn synth_latest(State(api): State<ApiState>, Path(which): Path<String>) -> Response {
    if which != "control" && which != "image" {
        return error(StatusCode::BAD_REQUEST, format!("{which:?}: ask for control or image"));
    }
    match api.state.synth() {
        Some(pair) => {
            let bytes = if which == "control" { pair.control_png } else { pair.image_png };
            image_response("image/png", pair.seq, bytes)
        }
        None => error(StatusCode::NOT_FOUND, "no synth job has produced an image yet"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn host_names_are_parsed_without_their_port() {
        assert_eq!(host_name("LocalHost:7700").as_deref(), Some("localhost"));
        assert_eq!(host_name("127.0.0.1").as_deref(), Some("127.0.0.1"));
        assert_eq!(host_name("[::1]:80").as_deref(), Some("[::1]"));
        assert_eq!(host_name("rig.lab.:7700").as_deref(), Some("rig.lab"));
        for bad in ["", "a b", "x:y", "[::1", "[::1]x", "user@host", "a:1:2", "h/p"] {
            assert_eq!(host_name(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn the_host_rule_answers_loopback_names_the_listen_ip_and_allowed_names() {
        let loopback = HostRule::new("127.0.0.1:7700".parse().expect("addr"), &[]);
        for ok in ["localhost:7700", "127.0.0.1:7700", "127.0.0.1:9999", "[::1]:7700", "localhost", "127.1.2.3"] {
            assert!(loopback.allows(ok), "{ok}");
        }
        // DNS rebinding: another site's name resolved to 127.0.0.1.
        for refused in ["attacker.example:7700", "localhost.attacker.example", "192.168.1.5:7700", "", "[::1"] {
            assert!(!loopback.allows(refused), "{refused}");
        }
        let lab = HostRule::new("192.168.1.20:7700".parse().expect("addr"), &["RigPC.lab".to_string()]);
        assert!(lab.allows("192.168.1.20:7700") && lab.allows("rigpc.lab:7700") && lab.allows("localhost:7700"));
        assert!(!lab.allows("192.168.1.21:7700") && !lab.allows("other.lab"));
        let any = HostRule::new("0.0.0.0:7700".parse().expect("addr"), &[]);
        assert!(any.allows("10.0.0.9:7700") && !any.allows("rig.lab:7700"));
    }
}
