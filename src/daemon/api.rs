//! The HTTP API (axum over the daemon's tokio runtime) and the page.
//!
//! | method and path | answer |
//! |---|---|
//! | `GET /` | the live page (HTML; it polls the API below) |
//! | `GET /api/status` | [`StatusView`](super::state::StatusView) |
//! | `GET /api/jobs` | every [`JobView`](super::state::JobView), oldest first |
//! | `POST /api/jobs` | queue a [`JobRequest`] (JSON body); 201 with the job |
//! | `GET /api/jobs/{id}` | one job |
//! | `POST /api/jobs/{id}/cancel`, `DELETE /api/jobs/{id}` | cancel it (a running job stops at its next safe point) |
//! | `GET /api/frames/{sensor}` | the sensor's latest frame (JPEG) |
//! | `GET /api/synth/latest/{control\|image}` | the latest control or synthetic image of a synth job (PNG) |
//!
//! With a token, every `/api/` request must carry `Authorization: Bearer <token>` (401
//! otherwise); the page itself is served without it and sends the token it was given in its
//! URL fragment (`/#token=...`, which browsers do not send to the server). Errors are JSON
//! `{"error": "..."}` with 400 (bad request), 401, 404 (no such job, sensor or image), 409
//! (cancelling a finished job) or 503 (the daemon is shutting down).

use std::sync::Arc;

use axum::Router;
use axum::body::Bytes;
use axum::extract::{Path, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::{get, post};
use serde_json::json;

use super::state::{CancelError, DaemonState};
use crate::jobs::JobRequest;

/// The page, one self-contained file.
pub const PAGE_HTML: &str = include_str!("page.html");

/// What every handler gets.
#[derive(Clone)]
pub struct ApiState {
    pub state: Arc<DaemonState>,
    /// `None`: no token needed (loopback only).
    pub token: Option<Arc<str>>,
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
    routes.route("/", get(page)).with_state(api)
}

fn error(status: StatusCode, message: impl Into<String>) -> Response {
    (status, axum::Json(json!({ "error": message.into() }))).into_response()
}

/// Constant-time comparison, so the token does not leak through response timing.
fn same_token(given: &[u8], expected: &[u8]) -> bool {
    given.len() == expected.len() && given.iter().zip(expected).fold(0u8, |acc, (a, b)| acc | (a ^ b)) == 0
}

async fn require_token(State(api): State<ApiState>, request: Request, next: Next) -> Response {
    if let Some(token) = &api.token {
        let given = request
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(str::trim);
        match given {
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

async fn list_jobs(State(api): State<ApiState>) -> Response {
    axum::Json(api.state.jobs()).into_response()
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
    let json_type = headers.get(header::CONTENT_TYPE).and_then(|v| v.to_str().ok()).is_none_or(|v| v.starts_with("application/json"));
    if !json_type {
        return error(StatusCode::BAD_REQUEST, "the body must be JSON (Content-Type: application/json)");
    }
    let spec: JobRequest = match serde_json::from_slice(&body) {
        Ok(spec) => spec,
        Err(e) => {
            return error(
                StatusCode::BAD_REQUEST,
                format!("bad job: {e} (expected {{\"kind\": \"collect\" | \"synth\" | \"calibrate\", ...the command's options}})"),
            );
        }
    };
    match api.state.submit(spec) {
        Some(job) => (StatusCode::CREATED, axum::Json(job)).into_response(),
        None => error(StatusCode::SERVICE_UNAVAILABLE, "the daemon is shutting down; no new jobs"),
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
