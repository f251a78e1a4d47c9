//! The console's HTTP side: the page, the REST/JSON API and its event stream. Every route but
//! the page's own files needs the token; every body is bounded and checked as the CLI checks
//! its flags; each request waits a bounded time for the driver.

use super::json::{self, CameraBody, CutsBody, LightsBody, PlaybackBody, QualityBody, VolumeBody};
use super::{Call, Shared};
use axum::extract::rejection::JsonRejection;
use axum::extract::{Path, Query, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::middleware::{self, Next};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Redirect, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde::Deserialize;
use serde_json::{json, Value};
use std::convert::Infallible;
use std::time::Duration;
use tessera_protocol::control::{ControlReply, ControlRequest, Playback, ViewName, WallStatus};

/// Largest request body accepted.
const MAX_BODY: usize = 64 * 1024;
/// Longest a request waits for the driver's answer.
const ANSWER_WAIT: Duration = Duration::from_secs(10);
/// Longest a snapshot waits for every display's files (the final quality may take a while).
const SNAPSHOT_WAIT: Duration = Duration::from_secs(300);
/// The cookie the page's token becomes.
const COOKIE: &str = "tessera_console";

const INDEX: &str = include_str!("../../console/index.html");
const SCRIPT: &str = include_str!("../../console/console.js");
const UTIL: &str = include_str!("../../console/util.js");
const STYLE: &str = include_str!("../../console/console.css");

/// An answer that is not a success: its status and reason, as `{"error": reason}`.
pub struct ApiError(StatusCode, String);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.0, Json(json!({ "error": self.1 }))).into_response()
    }
}

fn bad(e: impl std::fmt::Display) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, e.to_string())
}

fn bad_chain(e: anyhow::Error) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, format!("{e:#}"))
}

type ApiResult = Result<Json<Value>, ApiError>;

/// A JSON body, refused with its reason when it does not parse.
fn body<T>(parsed: Result<Json<T>, JsonRejection>) -> Result<T, ApiError> {
    parsed.map(|Json(t)| t).map_err(|e| bad(e.body_text()))
}

/// The routes, with the token checked before any of `/api`.
pub fn router(shared: Shared) -> Router {
    let api = Router::new()
        .route("/status", get(status))
        .route("/figures", get(figures))
        .route("/events", get(events))
        .route("/wall.png", get(wall_png))
        .route("/heatmap.png", get(heatmap_png))
        .route("/histogram", get(histogram))
        .route("/openapi.json", get(openapi))
        .route("/input", post(input))
        .route("/camera", post(camera))
        .route("/quality", post(quality))
        .route("/cuts", post(cuts))
        .route("/lights", post(lights))
        .route("/volume", post(volume))
        .route("/playback", post(playback))
        .route("/views", get(views))
        .route("/views/{name}", post(save_view))
        .route("/views/{name}/go", post(goto_view))
        .route("/overlay", post(overlay))
        .route("/snapshot", post(snapshot))
        .route("/probe", get(probe))
        .route("/record", post(record))
        .route("/replay", post(replay))
        .route("/particles", post(particles))
        .fallback(|| async { ApiError(StatusCode::NOT_FOUND, "no such API route".into()) })
        .route_layer(middleware::from_fn_with_state(shared.clone(), authorise));
    Router::new()
        .route("/", get(index))
        .route("/console.js", get(|| async { asset(SCRIPT, "text/javascript") }))
        .route("/util.js", get(|| async { asset(UTIL, "text/javascript") }))
        .route("/console.css", get(|| async { asset(STYLE, "text/css") }))
        .nest("/api", api)
        .layer(axum::extract::DefaultBodyLimit::max(MAX_BODY))
        .layer(tower_http::limit::RequestBodyLimitLayer::new(MAX_BODY))
        .layer(tower_http::set_header::SetResponseHeaderLayer::overriding(
            header::X_CONTENT_TYPE_OPTIONS,
            HeaderValue::from_static("nosniff"),
        ))
        .layer(tower_http::set_header::SetResponseHeaderLayer::overriding(
            header::CONTENT_SECURITY_POLICY,
            HeaderValue::from_static(
                "default-src 'self'; img-src 'self' data: blob:; style-src 'self'; frame-ancestors 'none'",
            ),
        ))
        .with_state(shared)
}

fn asset(text: &'static str, kind: &'static str) -> Response {
    ([(header::CONTENT_TYPE, kind)], text).into_response()
}

#[derive(Deserialize)]
struct TokenQuery {
    token: Option<String>,
}

/// The page; opened with the token, it sets the cookie and sends the browser to `/`.
async fn index(State(shared): State<Shared>, Query(q): Query<TokenQuery>) -> Response {
    match q.token {
        Some(t) if token_matches(&t, &shared.cfg.token) => {
            let cookie = format!("{COOKIE}={t}; HttpOnly; SameSite=Strict; Path=/");
            ([(header::SET_COOKIE, cookie)], Redirect::to("/")).into_response()
        }
        Some(_) => ApiError(StatusCode::UNAUTHORIZED, "wrong token".into()).into_response(),
        // The page itself is no secret: without a cookie its API calls say how to get in.
        None => asset(INDEX, "text/html; charset=utf-8"),
    }
}

/// Compares in time independent of where the first difference is.
fn token_matches(given: &str, token: &str) -> bool {
    given.len() == token.len()
        && given
            .bytes()
            .zip(token.bytes())
            .fold(0u8, |acc, (a, b)| acc | (a ^ b))
            == 0
}

fn authorised(headers: &HeaderMap, token: &str) -> bool {
    let bearer = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "));
    let cookie = headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().strip_prefix(COOKIE)?.strip_prefix('='))
        .find(|v| token_matches(v, token));
    bearer.is_some_and(|b| token_matches(b, token)) || cookie.is_some()
}

async fn authorise(State(shared): State<Shared>, request: Request, next: Next) -> Response {
    // Over HTTPS, a control certificate the cluster CA signed is as good as the token.
    let peer = request
        .extensions()
        .get::<axum::extract::ConnectInfo<super::tls::TlsPeer>>()
        .map(|p| p.0.clone());
    let certified = peer.as_ref().is_some_and(|p| p.control);
    if certified || authorised(request.headers(), &shared.cfg.token) {
        next.run(request).await
    } else {
        if let Some(p) = peer {
            tracing::info!(
                "console: refused {} without a token or a control certificate",
                p.addr
            );
        }
        ApiError(
            StatusCode::UNAUTHORIZED,
            "not authorised: open the console with the address tessera-master printed (its token), or send Authorization: Bearer TOKEN".into(),
        )
        .into_response()
    }
}

/// Hands `request` to the driver and waits (bounded) for its answer.
async fn ask(shared: &Shared, request: ControlRequest) -> Result<ControlReply, ApiError> {
    let (tx, rx) = tokio::sync::oneshot::channel();
    let unavailable = |why: &str| ApiError(StatusCode::SERVICE_UNAVAILABLE, why.into());
    shared
        .calls
        .try_send(Call { request, reply: tx })
        .map_err(|_| unavailable("the wall is busy or over; try again"))?;
    match tokio::time::timeout(ANSWER_WAIT, rx).await {
        Ok(Ok(ControlReply::Refused(why))) => {
            Err(ApiError(StatusCode::UNPROCESSABLE_ENTITY, why.to_string()))
        }
        Ok(Ok(reply)) => Ok(reply),
        Ok(Err(_)) => Err(unavailable("the wall is over")),
        Err(_) => Err(unavailable("the wall did not answer within 10 s")),
    }
}

/// A change's answer: the state id it makes and the first frame that shows it.
fn answered(reply: ControlReply) -> ApiResult {
    Ok(Json(match reply {
        ControlReply::Queued {
            changes,
            state_id,
            frame,
        } => json!({ "changes": changes, "state_id": state_id.0, "frame": frame }),
        ControlReply::Done => json!({ "done": true }),
        other => serde_json::to_value(&other).map_err(bad)?,
    }))
}

async fn change(shared: &Shared, request: ControlRequest) -> ApiResult {
    answered(ask(shared, request).await?)
}

/// The master's status of the wall.
async fn wall_status(shared: &Shared) -> Result<WallStatus, ApiError> {
    match ask(shared, ControlRequest::Status).await? {
        ControlReply::Status(s) => Ok(s),
        _ => Err(bad(
            "the master answered a status request with something else",
        )),
    }
}

async fn current_status(shared: &Shared) -> Result<json::StatusView, ApiError> {
    Ok(json::StatusView::of(
        &wall_status(shared).await?,
        &shared.cfg.wall,
    ))
}

async fn status(State(shared): State<Shared>) -> ApiResult {
    Ok(Json(
        serde_json::to_value(current_status(&shared).await?).map_err(bad)?,
    ))
}

async fn figures(State(shared): State<Shared>) -> ApiResult {
    match ask(&shared, ControlRequest::Figures).await? {
        ControlReply::Figures(f) => Ok(Json(serde_json::to_value(f).map_err(bad)?)),
        _ => Err(bad(
            "the master answered a figures request with something else",
        )),
    }
}

/// Server-sent events: `status` and `figures` as they change (at most every tick), and
/// `picture` when the wall's picture does. Each stream reads `watch` channels, which hold
/// only the newest value: a browser that reads slowly skips values, never queues them.
async fn events(
    State(shared): State<Shared>,
) -> Sse<impl futures_util::Stream<Item = Result<Event, Infallible>>> {
    let mut live = shared.live.clone();
    let mut picture = shared.picture_frame.clone();
    live.mark_changed();
    let stream = futures_util::stream::unfold(
        (live, picture.clone()),
        |(mut live, mut pic)| async {
            let events = tokio::select! {
                changed = live.changed() => {
                    changed.ok()?;
                    let now = live.borrow_and_update().clone();
                    let mut out = Vec::new();
                    if let Some(s) = &now.status {
                        out.push(Event::default().event("status").json_data(s).ok()?);
                    }
                    if let Some(f) = &now.figures {
                        out.push(Event::default().event("figures").json_data(f).ok()?);
                    }
                    out
                }
                changed = pic.changed() => {
                    changed.ok()?;
                    let frame = *pic.borrow_and_update();
                    vec![Event::default().event("picture").json_data(json!({ "frame": frame })).ok()?]
                }
            };
            Some((
                futures_util::stream::iter(events.into_iter().map(Ok)),
                (live, pic),
            ))
        },
    );
    picture.mark_unchanged();
    use futures_util::StreamExt;
    Sse::new(stream.flatten()).keep_alive(KeepAlive::default())
}

async fn wall_png(State(shared): State<Shared>) -> Response {
    let picture = shared.picture.clone();
    let png = tokio::task::spawn_blocking(move || {
        picture.lock().unwrap_or_else(|e| e.into_inner()).png()
    })
    .await;
    png_answer(png)
}

/// Which render node rendered each tile last, over the picture's size.
async fn heatmap_png(State(shared): State<Shared>) -> Response {
    let owners = match ask(&shared, ControlRequest::TileOwners).await {
        Ok(ControlReply::TileOwners(owners)) => owners,
        Ok(_) => return bad("the master answered with something else").into_response(),
        Err(e) => return e.into_response(),
    };
    let (picture, cfg) = (shared.picture.clone(), shared.cfg.clone());
    let png = tokio::task::spawn_blocking(move || {
        let picture = picture.lock().unwrap_or_else(|e| e.into_inner());
        picture.heatmap(&cfg.wall, &owners).png()
    })
    .await;
    png_answer(png)
}

fn png_answer(png: Result<Vec<u8>, tokio::task::JoinError>) -> Response {
    match png {
        Ok(bytes) => (
            [
                (header::CONTENT_TYPE, "image/png"),
                (header::CACHE_CONTROL, "no-store"),
            ],
            bytes,
        )
            .into_response(),
        Err(e) => bad(e).into_response(),
    }
}

/// The colour map of particles' attributes.
async fn particles(
    State(shared): State<Shared>,
    parsed: Result<Json<json::ParticlesBody>, JsonRejection>,
) -> ApiResult {
    let map = tessera_cli::parse_colormap(&body(parsed)?.colormap).map_err(bad)?;
    let status = wall_status(&shared).await?;
    if status.particle_range.is_none() {
        return Err(ApiError(
            StatusCode::UNPROCESSABLE_ENTITY,
            "the scene has no particles to colour".into(),
        ));
    }
    let colour = tessera_model::state::StateChange::ColorMap(map);
    change(&shared, ControlRequest::Change(vec![colour])).await
}

async fn histogram(State(shared): State<Shared>) -> Response {
    match &shared.cfg.histogram {
        Some(h) => Json(h).into_response(),
        None => ApiError(StatusCode::NOT_FOUND, "the scene has no volume".into()).into_response(),
    }
}

async fn openapi() -> Json<Value> {
    Json(super::openapi::document())
}

async fn input(
    State(shared): State<Shared>,
    event: Result<Json<tessera_model::input::InputEvent>, JsonRejection>,
) -> ApiResult {
    change(&shared, ControlRequest::Input(body(event)?)).await
}

async fn camera(
    State(shared): State<Shared>,
    parsed: Result<Json<CameraBody>, JsonRejection>,
) -> ApiResult {
    let b = body(parsed)?;
    let now = current_status(&shared).await?.camera;
    let camera = tessera_model::camera::Camera::new(
        glam::Vec3::from_array(now.eye),
        glam::Vec3::from_array(now.target),
        glam::Vec3::from_array(now.up),
        now.fov,
    )
    .map_err(bad)?;
    let request = json::camera_request(&b, &camera, shared.cfg.home).map_err(bad_chain)?;
    change(&shared, request).await
}

async fn quality(
    State(shared): State<Shared>,
    parsed: Result<Json<QualityBody>, JsonRejection>,
) -> ApiResult {
    let request = json::quality_request(&body(parsed)?).map_err(bad_chain)?;
    change(&shared, request).await
}

async fn cuts(
    State(shared): State<Shared>,
    parsed: Result<Json<CutsBody>, JsonRejection>,
) -> ApiResult {
    let request = json::cuts_request(&body(parsed)?).map_err(bad_chain)?;
    change(&shared, request).await
}

async fn lights(
    State(shared): State<Shared>,
    parsed: Result<Json<LightsBody>, JsonRejection>,
) -> ApiResult {
    let request = json::lights_request(&body(parsed)?).map_err(bad_chain)?;
    change(&shared, request).await
}

async fn volume(
    State(shared): State<Shared>,
    parsed: Result<Json<VolumeBody>, JsonRejection>,
) -> ApiResult {
    let b = body(parsed)?;
    let status = wall_status(&shared).await?;
    if status.volume_range.is_none() && status.series.is_none() {
        return Err(ApiError(
            StatusCode::UNPROCESSABLE_ENTITY,
            "the scene has no volume".into(),
        ));
    }
    let request = json::volume_request(&b, *status.state.params.volume()).map_err(bad_chain)?;
    change(&shared, request).await
}

async fn playback(
    State(shared): State<Shared>,
    parsed: Result<Json<PlaybackBody>, JsonRejection>,
) -> ApiResult {
    let b = body(parsed)?;
    let request = ControlRequest::Playback(Playback {
        playing: b.playing,
        steps_per_second: b.speed,
        step_by: b.step,
    });
    change(&shared, request).await
}

async fn views(State(shared): State<Shared>) -> ApiResult {
    answered(ask(&shared, ControlRequest::Views).await?)
}

async fn save_view(State(shared): State<Shared>, Path(name): Path<String>) -> ApiResult {
    let name = ViewName::new(&name).map_err(bad)?;
    change(&shared, ControlRequest::SaveView(name)).await
}

async fn goto_view(State(shared): State<Shared>, Path(name): Path<String>) -> ApiResult {
    let name = ViewName::new(&name).map_err(bad)?;
    change(&shared, ControlRequest::GotoView(name)).await
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct OverlayBody {
    on: bool,
}

async fn overlay(
    State(shared): State<Shared>,
    parsed: Result<Json<OverlayBody>, JsonRejection>,
) -> ApiResult {
    change(&shared, ControlRequest::Overlay(body(parsed)?.on)).await
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct SnapshotBody {
    #[serde(default, rename = "final")]
    final_quality: bool,
}

/// A snapshot, answered once every display wrote its file and the wall's is put together.
async fn snapshot(
    State(shared): State<Shared>,
    parsed: Result<Json<SnapshotBody>, JsonRejection>,
) -> ApiResult {
    let final_quality = body(parsed)?.final_quality;
    let mut done = shared.snapshots.subscribe();
    let ControlReply::Snapshot { frame, shown } =
        ask(&shared, ControlRequest::Snapshot { final_quality }).await?
    else {
        return Err(bad("the master answered a snapshot with something else"));
    };
    let wait = async {
        loop {
            match done.recv().await {
                // A final-quality snapshot's frame is the one the wall converges at, later.
                Ok(d) if d.frame == frame || final_quality && !shown && d.frame >= frame => {
                    return Some(d)
                }
                Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(_) => return None,
            }
        }
    };
    match tokio::time::timeout(SNAPSHOT_WAIT, wait).await {
        Ok(Some(d)) => Ok(Json(json!({
            "frame": d.frame,
            "shown": shown,
            "files": d.files,
            "failed_displays": d.failed_displays,
        }))),
        _ => Err(ApiError(
            StatusCode::GATEWAY_TIMEOUT,
            format!(
                "frame {frame} was not saved by every display within {} s",
                SNAPSHOT_WAIT.as_secs()
            ),
        )),
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RecordBody {
    on: bool,
    /// A file name in the sessions' folder (`--out`, else the working directory).
    path: Option<String>,
}

/// A plain file name: the console writes and reads sessions in one folder only.
fn session_name(name: &str) -> Result<&str, ApiError> {
    let plain = !name.is_empty()
        && name.len() <= 128
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        && !name.starts_with('.');
    if plain {
        Ok(name)
    } else {
        Err(bad(format!(
            "session file {name:?} must be a plain name (letters, digits, '-', '_', '.')"
        )))
    }
}

/// Starts or stops recording the session, in the sessions' folder.
async fn record(
    State(shared): State<Shared>,
    parsed: Result<Json<RecordBody>, JsonRejection>,
) -> ApiResult {
    let b = body(parsed)?;
    let start = if b.on {
        let default = format!("session-{}.jsonl", tessera_net::unix_ns() / 1_000_000_000);
        let name = session_name(b.path.as_deref().unwrap_or(&default))?;
        Some(shared.sessions.join(name))
    } else {
        None
    };
    let (tx, rx) = tokio::sync::oneshot::channel();
    let busy = || {
        ApiError(
            StatusCode::SERVICE_UNAVAILABLE,
            "the wall is busy or over".into(),
        )
    };
    shared
        .records
        .try_send(super::RecordCall { start, reply: tx })
        .map_err(|_| busy())?;
    match tokio::time::timeout(ANSWER_WAIT, rx).await {
        Ok(Ok(Ok(path))) => Ok(Json(json!({ "recording": path.is_some(), "path": path }))),
        Ok(Ok(Err(why))) => Err(ApiError(StatusCode::UNPROCESSABLE_ENTITY, why)),
        _ => Err(busy()),
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ReplayBody {
    path: String,
}

/// Replays a recorded session from the sessions' folder, from the next frame on.
async fn replay(
    State(shared): State<Shared>,
    parsed: Result<Json<ReplayBody>, JsonRejection>,
) -> ApiResult {
    let b = body(parsed)?;
    let path = shared.sessions.join(session_name(&b.path)?);
    let session = crate::record::Session::load(&path).map_err(bad_chain)?;
    let changes = session.changes();
    let first = changes.first().map_or(0, |(f, _)| f.0);
    let states = changes.into_iter().map(|(f, s)| (f.0 - first, s)).collect();
    change(&shared, ControlRequest::Replay(states)).await
}

#[derive(Deserialize)]
struct ProbeQuery {
    x: u32,
    y: u32,
}

async fn probe(
    State(shared): State<Shared>,
    query: Result<Query<ProbeQuery>, axum::extract::rejection::QueryRejection>,
) -> ApiResult {
    let Query(q) = query.map_err(|e| bad(e.body_text()))?;
    match ask(&shared, ControlRequest::Probe { x: q.x, y: q.y }).await? {
        ControlReply::Probe(hit) => Ok(Json(serde_json::to_value(hit).map_err(bad)?)),
        _ => Err(bad("the master answered a probe with something else")),
    }
}
