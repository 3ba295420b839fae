//! The status page: a small HTTP server with a live page (latest thickness map with its
//! out-of-tolerance overlay and verdict, the trend with its control limits, the alarms; it
//! polls `/api/latest` every second), `/api/latest`, `/api/history`, `/latest.png` and
//! Prometheus `/metrics`.
//!
//! Nothing a client does can stop or slow a measurement: the server is hyper's HTTP/1 on a
//! single-threaded tokio runtime on a thread of its own (one thread whatever the number of
//! clients), sharing only the page's state, which each side holds for a copy at most. At
//! most [`MAX_CONNECTIONS`] connections are served at once (further ones are closed as
//! they come); a request head has [`HEAD_TIMEOUT`] to arrive and at most [`MAX_HEAD_BYTES`]
//! (else 431 and the connection is closed); a request body is never read, whatever its
//! `Content-Length`; every connection is closed after its response, and after
//! [`CONNECTION_TIMEOUT`] whatever it does. Only `GET` and `HEAD` are answered.
//!
//! What the page shows is a [`StatusBoard`]; `inspect` leaves it in its output folder
//! ([`SNAPSHOT_FILE`]) after every sample, and `filmscope status` serves it from there
//! ([`StatusState::load`]) once `inspect` has stopped.

use super::folder::{FolderError, FolderProblem};
use std::borrow::Cow;
use std::collections::VecDeque;
use std::convert::Infallible;
use std::net::SocketAddr;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use http_body_util::Full;
use hyper::body::{Bytes, Incoming};
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use prometheus_client::encoding::{EncodeMetric, MetricEncoder, NoLabelSet};
use prometheus_client::metrics::counter::ConstCounter;
use prometheus_client::metrics::gauge::ConstGauge;
use prometheus_client::metrics::MetricType;
use prometheus_client::registry::Registry;
use serde::Serialize;
use serde_json::Value;

use super::listen::ServerThread;
use super::recipe::Recipe;
use super::spc::{self, Capability, History, Limits, Point, Variable};
use crate::record::line::{AlarmRecord, Record, ReferenceRecord, SampleRecord};

/// Most connections served at once (each a task of a few kB, not a thread).
pub const MAX_CONNECTIONS: usize = 512;
/// Most bytes of a request's head (request line and headers).
pub const MAX_HEAD_BYTES: usize = 16 * 1024;
/// Time a client has to send its request head.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(5);
/// Longest a connection is kept open, whatever the client does.
pub const CONNECTION_TIMEOUT: Duration = Duration::from_secs(20);

/// Seconds without a new sample after which the page shows STALE, unless the recipe's
/// `[status] stale_after_s` says otherwise.
pub const DEFAULT_STALE_AFTER_S: f64 = 600.0;

/// Alarms the page and `/api/latest` show.
pub const RECENT_ALARMS: usize = 50;

/// The server could not start.
#[derive(Debug, thiserror::Error)]
#[error("status page on {addr}: {problem}")]
pub struct StatusError {
    /// Where it was to listen.
    pub addr: String,
    /// Why it could not.
    pub problem: super::listen::ListenError,
}

/// What the page shows; also what `inspect` leaves in its output folder
/// ([`SNAPSHOT_FILE`]) after every sample, for `filmscope status` to serve when it has
/// stopped.
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct StatusState {
    /// The latest sample record.
    #[serde(serialize_with = "crate::record::sorted")]
    pub latest: Option<SampleRecord>,
    /// Its overlay PNG (not in the snapshot: read from the sample's folder).
    #[serde(skip)]
    pub latest_png: Option<Vec<u8>>,
    /// `/api/history`'s body ([`HistoryBody`] as JSON: the page's chart data, its limits
    /// and capabilities null until there are samples enough).
    pub history: Value,
    /// Recent alarm records, newest last.
    #[serde(serialize_with = "crate::record::sorted")]
    pub alarms: VecDeque<AlarmRecord>,
    /// Samples, passed, failed and alarms since start.
    pub counts: Counts,
    /// Pages served (`/`).
    #[serde(skip)]
    pub page_hits: u64,
    /// The film, for the title.
    pub film: String,
    /// The last reference check's record.
    #[serde(serialize_with = "crate::record::sorted")]
    pub reference: Option<ReferenceRecord>,
    /// Seconds without a new sample after which the page shows STALE.
    pub stale_after_s: f64,
    /// The metrics' labels: the line's name and the recipe's file name.
    pub labels: (String, String),
    /// When the latest sample was shown.
    pub latest_at: Option<std::time::SystemTime>,
    /// Latency (last row to verdict published) histogram: counts per
    /// [`LATENCY_BUCKETS_S`] bucket (cumulative when written), their sum in seconds.
    pub latency: ([u64; LATENCY_BUCKETS_S.len()], f64),
}

/// Upper bounds of the latency histogram's buckets, seconds (`+Inf` besides).
pub const LATENCY_BUCKETS_S: [f64; 10] = [0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0];

/// Counters for `/metrics`.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Counts {
    /// Samples.
    pub samples: u64,
    /// Passed.
    pub passed: u64,
    /// Failed.
    pub failed: u64,
    /// Alarms.
    pub alarms: u64,
}

/// The file of an output folder that holds the page's state after every sample.
pub const SNAPSHOT_FILE: &str = "status.json";

/// Most records of the results log shown beyond the snapshot (all of them when there is
/// none).
pub const CATCH_UP_RECORDS: usize = 10_000;

/// Most bytes of a [`SNAPSHOT_FILE`] read back (the history's points at the recipe's most).
pub const MAX_SNAPSHOT_BYTES: u64 = 64 << 20;

/// The page's state, shared between whoever publishes to it and the server that shows it
/// (cloning shares it).
#[derive(Clone, Debug)]
pub struct StatusBoard {
    state: Arc<Mutex<StatusState>>,
}

impl StatusBoard {
    /// An empty board: no sample yet, for `film`.
    pub fn new(film: &str) -> Self {
        Self::from_state(StatusState::empty(film))
    }

    /// A board showing `state`.
    pub fn from_state(state: StatusState) -> Self {
        Self {
            state: Arc::new(Mutex::new(state)),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, StatusState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Shows a new sample: its record, overlay PNG, the history body and its alarms.
    pub fn publish_sample(
        &self,
        record: &SampleRecord,
        png: Option<Vec<u8>>,
        history: Value,
        alarms: &[AlarmRecord],
    ) {
        let mut s = self.lock();
        s.counts.samples += 1;
        if record.verdict.passed() {
            s.counts.passed += 1;
        } else {
            s.counts.failed += 1;
        }
        s.latest = Some(record.clone());
        s.latest_at = Some(std::time::SystemTime::now());
        let sec = record.latency_ms / 1000.0;
        if let Some(b) = LATENCY_BUCKETS_S.iter().position(|&le| sec <= le) {
            s.latency.0[b] += 1;
        }
        s.latency.1 += sec;
        if png.is_some() {
            s.latest_png = png;
        }
        s.history = history;
        for a in alarms {
            s.counts.alarms += 1;
            s.alarms.push_back(a.clone());
            while s.alarms.len() > RECENT_ALARMS {
                s.alarms.pop_front();
            }
        }
    }

    /// Shows `record`, a sample measured before this start, as the latest (not counted):
    /// its overlay PNG and time from its folder under `dir`.
    pub fn show_last(&self, record: &SampleRecord, dir: &Path) {
        let mut s = self.lock();
        s.latest = Some(record.clone());
        if let Some(f) = record_folder(&record.folder) {
            let f = dir.join(f);
            s.latest_png = std::fs::read(f.join("overlay.png")).ok();
            s.latest_at = std::fs::metadata(f.join("record.json"))
                .and_then(|m| m.modified())
                .ok();
        }
    }

    /// Shows an alarm that belongs to no sample (the disk below its free-space floor).
    pub fn publish_alarm(&self, alarm: &AlarmRecord) {
        let mut s = self.lock();
        s.counts.alarms += 1;
        s.alarms.push_back(alarm.clone());
        while s.alarms.len() > RECENT_ALARMS {
            s.alarms.pop_front();
        }
    }

    /// The metrics' labels: `line` (the recipe's `line`) and `recipe` (its file name).
    pub fn set_labels(&self, line: &str, recipe: &str) {
        self.lock().labels = (line.to_owned(), recipe.to_owned());
    }

    /// Seconds without a new sample after which the page shows STALE.
    pub fn set_stale_after(&self, seconds: f64) {
        self.lock().stale_after_s = seconds;
    }

    /// Shows a reference check's record (its age on the page counts from its timestamp).
    pub fn publish_reference(&self, record: &ReferenceRecord) {
        self.lock().reference = Some(record.clone());
    }

    /// Replaces `/api/history`'s body.
    pub fn set_history(&self, history: Value) {
        self.lock().history = history;
    }

    /// Pages served so far.
    pub fn page_hits(&self) -> u64 {
        self.lock().page_hits
    }

    /// The latest sample's id, if any.
    pub fn latest_id(&self) -> Option<String> {
        self.lock().latest.as_ref().map(|l| l.sample_id.clone())
    }

    /// Writes the state (all but the PNG, which stays in the sample's folder) to
    /// `dir/`[`SNAPSHOT_FILE`]: to a temporary file, renamed over the old one.
    pub fn write_snapshot(&self, dir: &Path) -> std::io::Result<()> {
        let bytes = serde_json::to_vec(&*self.lock()).map_err(std::io::Error::other)?;
        crate::io::write_atomic(&dir.join(SNAPSHOT_FILE), &bytes)
    }
}

impl StatusState {
    /// No sample yet, for `film`.
    pub fn empty(film: &str) -> Self {
        Self {
            history: HistoryBody::default().to_value(),
            film: film.to_owned(),
            stale_after_s: DEFAULT_STALE_AFTER_S,
            ..Self::default()
        }
    }

    /// The state `inspect` left in `dir` ([`SNAPSHOT_FILE`]), brought up to date with the
    /// records of its results log that came after it (a stop between a record and the
    /// snapshot; a folder without a snapshot shows its newest [`CATCH_UP_RECORDS`]), and
    /// the latest sample's overlay PNG read from its folder. The problem in one line when
    /// `dir` has neither a snapshot nor a results log, or they cannot be read.
    pub fn load(dir: &Path) -> Result<Self, FolderError> {
        let path = dir.join(SNAPSHOT_FILE);
        let e = |x: FolderProblem| FolderError::new(&path, x);
        let mut state = match std::fs::File::open(&path) {
            Ok(file) => {
                let len = file.metadata().map_err(|x| e(x.into()))?.len();
                if len > MAX_SNAPSHOT_BYTES {
                    return Err(e(FolderProblem::TooLarge {
                        len,
                        max: MAX_SNAPSHOT_BYTES,
                    }));
                }
                serde_json::from_reader(std::io::BufReader::new(file)).map_err(|x| e(x.into()))?
            }
            Err(x) if x.kind() == std::io::ErrorKind::NotFound => {
                let log = super::stream::ResultsLog::path_in(dir);
                if !log.is_file() {
                    let problem = FolderProblem::NotALineFolder(SNAPSHOT_FILE);
                    return Err(FolderError::new(dir, problem));
                }
                StatusState::empty("")
            }
            Err(x) => return Err(e(x.into())),
        };
        let seen = [
            state.latest.as_ref().and_then(|r| r.seq),
            state.alarms.iter().filter_map(|r| r.seq).max(),
            state.reference.as_ref().and_then(|r| r.seq),
        ]
        .into_iter()
        .flatten()
        .max()
        .unwrap_or(0);
        let keep = usize::try_from(super::recipe::MAX_RESULTS_KEEP).unwrap_or(usize::MAX);
        let (newer, _) = super::stream::records_after(dir, keep, seen, CATCH_UP_RECORDS)?;
        for r in &newer {
            state.catch_up(r);
        }
        let caught_up_sample = newer.iter().any(|r| r.as_sample().is_some());
        if let Some(f) = state.latest.as_ref().and_then(|r| record_folder(&r.folder)) {
            let f = dir.join(f);
            state.latest_png = std::fs::read(f.join("overlay.png")).ok();
            if caught_up_sample {
                // Its record was written when it was published.
                state.latest_at = std::fs::metadata(f.join("record.json"))
                    .and_then(|m| m.modified())
                    .ok();
            }
        }
        Ok(state)
    }

    /// Shows a record of the results log the snapshot does not hold: a sample (counted,
    /// the latest, a point of the history), an alarm or a reference check.
    fn catch_up(&mut self, r: &Record) {
        match r {
            Record::Sample(r) => {
                self.counts.samples += 1;
                if r.verdict.passed() {
                    self.counts.passed += 1;
                } else {
                    self.counts.failed += 1;
                }
                if self.film.is_empty() {
                    self.film.clone_from(&r.film);
                }
                let point = Point::of(r);
                if let (Some(p), Ok(point)) = (
                    self.history["points"].as_array_mut(),
                    serde_json::to_value(point),
                ) {
                    p.push(point);
                }
                self.latest = Some((**r).clone());
            }
            Record::Alarm(a) => {
                self.counts.alarms += 1;
                self.alarms.push_back(a.clone());
                while self.alarms.len() > RECENT_ALARMS {
                    self.alarms.pop_front();
                }
            }
            Record::Reference(r) => self.reference = Some(r.clone()),
        }
    }
}

/// The folder a record names (`folder`), taken only as a relative path that stays inside
/// the output folder.
fn record_folder(folder: &str) -> Option<&Path> {
    Some(Path::new(folder)).filter(|f| {
        f.components()
            .all(|c| matches!(c, std::path::Component::Normal(_)))
    })
}

/// `/api/history`'s body: the history's points, oldest first, each variable's control
/// limits and the capability against the recipe's tolerances (null until the history
/// holds enough samples), and the tolerances.
#[derive(Clone, Debug, Default, Serialize)]
pub struct HistoryBody {
    /// The points.
    pub points: Vec<Point>,
    /// Control limits by variable.
    pub limits: std::collections::BTreeMap<&'static str, Option<Limits>>,
    /// Cpk and Ppk of the mean thickness and of the index.
    pub capability: std::collections::BTreeMap<&'static str, Option<Capability>>,
    /// The recipe's tolerances (none on an empty board).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spec: Option<SpecLimits>,
}

/// The recipe's tolerances on the trend charts.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SpecLimits {
    /// Lower thickness limit, nm.
    pub lsl: f64,
    /// Upper thickness limit, nm.
    pub usl: f64,
    /// Lower index limit.
    pub index_lsl: f64,
    /// Upper index limit.
    pub index_usl: f64,
}

impl HistoryBody {
    /// The body of `history` against `recipe`'s tolerances and SPC settings.
    pub fn new(history: &History, recipe: &Recipe) -> Self {
        let s = &recipe.spc;
        let [lsl, usl] = recipe.thickness.limits();
        let ix = &recipe.index;
        let (index_lsl, index_usl) = (ix.nominal - ix.tolerance, ix.nominal + ix.tolerance);
        let limits = Variable::ALL
            .iter()
            .map(|&v| {
                (
                    v.name(),
                    spc::limits_of(history, v, s.baseline, s.min_points),
                )
            })
            .collect();
        let capability = [
            (Variable::ThicknessMeanNm, lsl, usl),
            (Variable::RefractiveIndex, index_lsl, index_usl),
        ]
        .into_iter()
        .map(|(v, lo, hi)| (v.name(), spc::capability(&history.series(v), lo, hi)))
        .collect();
        Self {
            points: history.points().cloned().collect(),
            limits,
            capability,
            spec: Some(SpecLimits {
                lsl,
                usl,
                index_lsl,
                index_usl,
            }),
        }
    }

    /// As JSON, the keys of every object in alphabetical order.
    pub fn to_value(&self) -> Value {
        serde_json::to_value(self).unwrap_or_default()
    }
}

/// A running status server; stops when dropped. It shows a [`StatusBoard`] (its methods
/// are the board's).
pub struct StatusServer {
    board: StatusBoard,
    server: ServerThread,
}

impl std::ops::Deref for StatusServer {
    type Target = StatusBoard;
    fn deref(&self) -> &StatusBoard {
        &self.board
    }
}

impl StatusServer {
    /// Listens on `bind:port` (port 0: any free one) with an empty board for `film`. Fails,
    /// naming the address, when it cannot listen there (the port in use, an address not of
    /// this machine).
    pub fn start(bind: &str, port: u16, film: &str) -> Result<Self, StatusError> {
        Self::serve(bind, port, StatusBoard::new(film))
    }

    /// Listens on `bind:port` (port 0: any free one) and shows `board`. Fails as
    /// [`start`](Self::start) does.
    pub fn serve(bind: &str, port: u16, board: StatusBoard) -> Result<Self, StatusError> {
        let st = board.state.clone();
        let server = ServerThread::start((bind, port), "status", move |listener, stopped| {
            serve(listener, st, stopped)
        })
        .map_err(|problem| StatusError {
            addr: format!("{bind}:{port}"),
            problem,
        })?;
        Ok(Self { board, server })
    }

    /// Where it listens.
    pub fn addr(&self) -> SocketAddr {
        self.server.addr()
    }

    /// The page's URL.
    pub fn url(&self) -> String {
        format!("http://{}/", self.server.addr())
    }

    /// Shows `state` instead of what it showed (the pages served still counted).
    pub fn show(&self, state: StatusState) {
        let mut s = self.board.lock();
        let hits = s.page_hits;
        *s = state;
        s.page_hits = hits;
    }
}

/// Accepts connections until `stopped`, each served as a task under the bounds of the
/// [module docs](self); dropping the runtime after it ends every connection still open.
async fn serve(
    listener: std::net::TcpListener,
    state: Arc<Mutex<StatusState>>,
    mut stopped: tokio::sync::oneshot::Receiver<()>,
) {
    let Ok(listener) = tokio::net::TcpListener::from_std(listener) else {
        return;
    };
    let permits = Arc::new(tokio::sync::Semaphore::new(MAX_CONNECTIONS));
    loop {
        let accepted = tokio::select! {
            _ = &mut stopped => return,
            a = listener.accept() => a,
        };
        let stream = match accepted {
            Ok((stream, _)) => stream,
            // Out of file descriptors or the like: wait a moment rather than spin.
            Err(_) => {
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let Ok(permit) = permits.clone().try_acquire_owned() else {
            drop(stream);
            continue;
        };
        let st = state.clone();
        tokio::spawn(async move {
            let _permit = permit;
            let service = hyper::service::service_fn(move |req: Request<Incoming>| {
                let st = st.clone();
                async move { Ok::<_, Infallible>(respond(&req, &st)) }
            });
            let mut http = hyper::server::conn::http1::Builder::new();
            http.timer(TokioTimer::new())
                .header_read_timeout(HEAD_TIMEOUT)
                .max_buf_size(MAX_HEAD_BYTES)
                .keep_alive(false);
            let conn = http.serve_connection(TokioIo::new(stream), service);
            let _ = tokio::time::timeout(CONNECTION_TIMEOUT, conn).await;
        });
    }
}

/// The response to one request (its body never read).
fn respond(req: &Request<Incoming>, st: &Mutex<StatusState>) -> Response<Full<Bytes>> {
    let (body, ctype, code) = if req.method() == Method::GET || req.method() == Method::HEAD {
        route(req.uri().path(), st)
    } else {
        (b"only GET".to_vec(), "text/plain", 405)
    };
    let mut resp = Response::new(Full::new(Bytes::from(body)));
    *resp.status_mut() = StatusCode::from_u16(code).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR);
    let headers = resp.headers_mut();
    headers.insert(
        hyper::header::CONTENT_TYPE,
        hyper::header::HeaderValue::from_static(ctype),
    );
    headers.insert(
        hyper::header::CACHE_CONTROL,
        hyper::header::HeaderValue::from_static("no-store"),
    );
    resp
}

fn route(url: &str, st: &Mutex<StatusState>) -> (Vec<u8>, &'static str, u16) {
    let path = url.split('?').next().unwrap_or("/");
    let mut s = st.lock().unwrap_or_else(|p| p.into_inner());
    match path {
        "/" | "/index.html" => {
            s.page_hits += 1;
            (page(&s).into_bytes(), "text/html; charset=utf-8", 200)
        }
        "/api/latest" => (latest(&s).into_bytes(), "application/json", 200),
        "/api/history" => (s.history.to_string().into_bytes(), "application/json", 200),
        "/metrics" => (metrics(&s).into_bytes(), METRICS_CONTENT_TYPE, 200),
        "/latest.png" => match &s.latest_png {
            Some(p) => (p.clone(), "image/png", 200),
            None => (b"no sample yet".to_vec(), "text/plain", 404),
        },
        _ => (b"not found".to_vec(), "text/plain", 404),
    }
}

/// `/api/latest`'s body.
#[derive(Serialize)]
struct Latest<'a> {
    sample: &'a Option<SampleRecord>,
    alarms: Vec<&'a AlarmRecord>,
    counts: Counts,
    reference: &'a Option<ReferenceRecord>,
    stale_after_s: f64,
}

fn latest(s: &StatusState) -> String {
    let body = Latest {
        sample: &s.latest,
        alarms: s.alarms.iter().rev().take(10).collect(),
        counts: s.counts,
        reference: &s.reference,
        stale_after_s: s.stale_after_s,
    };
    crate::record::to_json(&body).unwrap_or_default()
}

/// Prometheus text exposition (format 0.0.4, [`METRICS_CONTENT_TYPE`]) of the counters, the
/// latency histogram, the latest sample and the capability, every series labelled `line`
/// and `recipe` ([`StatusState::labels`]). A registry of constant metrics is built from the
/// state at each request, as `filmscope status` serves a state read back from a file.
fn metrics(s: &StatusState) -> String {
    let (line, recipe) = s.labels.clone();
    let mut registry = Registry::with_labels(
        [
            (Cow::Borrowed("line"), Cow::Owned(line)),
            (Cow::Borrowed("recipe"), Cow::Owned(recipe)),
        ]
        .into_iter(),
    );
    register_counts(&mut registry, s);
    register_latest(&mut registry, s);
    let mut text = String::new();
    // Writing into a String cannot fail.
    let _ = prometheus_client::encoding::prometheus_text::encode(&mut text, &registry);
    text
}

/// `/metrics`' `Content-Type`: the Prometheus text format, version 0.0.4.
const METRICS_CONTENT_TYPE: &str = prometheus_client::encoding::prometheus_text::CONTENT_TYPE;

/// A gauge of the value `v` (the registry ends `help` with a full stop).
fn gauge(registry: &mut Registry, name: &str, help: &str, v: f64) {
    registry.register(name, help, ConstGauge::new(v));
}

/// The latency histogram, the time of the latest sample and the counters since start
/// (registered as `filmscope_samples` and so on: the encoder adds `_total`).
fn register_counts(registry: &mut Registry, s: &StatusState) {
    let (buckets, sum) = s.latency;
    registry.register(
        "filmscope_latency_seconds",
        "Last row of the sweep to the verdict published",
        LatencyHistogram {
            buckets: LATENCY_BUCKETS_S.iter().copied().zip(buckets).collect(),
            sum,
            count: s.counts.samples.max(buckets.iter().sum()),
        },
    );
    if let Some(t) = s.latest_at {
        let secs = t
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(f64::NAN, |d| d.as_secs_f64());
        gauge(
            registry,
            "filmscope_last_sample_timestamp_seconds",
            "When the latest sample's verdict was published, Unix time",
            secs,
        );
    }
    let c = s.counts;
    for (name, help, n) in [
        ("filmscope_samples", "Samples measured", c.samples),
        ("filmscope_samples_passed", "Samples that passed", c.passed),
        ("filmscope_samples_failed", "Samples that failed", c.failed),
        ("filmscope_alarms", "Run-rule alarms raised", c.alarms),
    ] {
        registry.register(name, help, ConstCounter::new(n));
    }
}

/// The latest sample's verdict, index, thickness, valid share and latency (when there is
/// one), and the mean thickness's Cpk and Ppk over the history (when it has them).
fn register_latest(registry: &mut Registry, s: &StatusState) {
    if let Some(l) = &s.latest {
        registry.register(
            "filmscope_last_pass",
            "1 if the latest sample passed",
            ConstGauge::new(i64::from(l.verdict.passed())),
        );
        let f = |v: Option<f64>| v.unwrap_or(f64::NAN);
        for (name, help, v) in [
            (
                "filmscope_last_refractive_index",
                "Index of the latest sample",
                f(l.refractive_index),
            ),
            (
                "filmscope_last_thickness_mean_nm",
                "Mean thickness of the latest sample, nm",
                f(l.thickness_nm.mean),
            ),
            (
                "filmscope_last_thickness_std_nm",
                "Thickness spread of the latest sample, nm",
                f(l.thickness_nm.std),
            ),
            (
                "filmscope_last_valid_fraction",
                "Valid share of the latest sample",
                l.valid_fraction,
            ),
            (
                "filmscope_last_latency_seconds",
                "Last row to verdict published, latest sample",
                l.latency_ms / 1000.0,
            ),
        ] {
            gauge(registry, name, help, v);
        }
    }
    let cap = &s.history["capability"]["thickness_mean_nm"];
    for (key, name, help) in [
        (
            "cpk",
            "filmscope_thickness_cpk",
            "Cpk of the mean thickness over the history",
        ),
        (
            "ppk",
            "filmscope_thickness_ppk",
            "Ppk of the mean thickness over the history",
        ),
    ] {
        if let Some(v) = cap[key].as_f64() {
            gauge(registry, name, help, v);
        }
    }
}

/// The latency histogram as the state holds it (a count per bucket, not cumulative; the
/// encoder sums them and adds `+Inf` with `count`), for the registry.
#[derive(Debug)]
struct LatencyHistogram {
    /// Each bucket's upper bound, seconds, and its count.
    buckets: Vec<(f64, u64)>,
    /// The latencies' sum, seconds.
    sum: f64,
    /// Samples, those above the last bound included.
    count: u64,
}

impl EncodeMetric for LatencyHistogram {
    fn encode(&self, mut encoder: MetricEncoder) -> std::fmt::Result {
        encoder.encode_histogram::<NoLabelSet>(self.sum, self.count, &self.buckets, None)
    }

    fn metric_type(&self) -> MetricType {
        MetricType::Histogram
    }
}

/// The status page (`templates/status.html`): the film and the latest sample's id, which
/// askama escapes for HTML; its script draws the rest from `/api/latest` and
/// `/api/history`, escaping the records' text itself.
#[derive(askama::Template)]
#[template(path = "status.html")]
struct Page<'a> {
    /// The recipe's film, the page's title.
    film: &'a str,
    /// The latest sample's id (`none yet`).
    sample_id: &'a str,
}

/// The page's HTML for the state `s`.
fn page(s: &StatusState) -> String {
    use askama::Template;
    let id = s
        .latest
        .as_ref()
        .map_or("none yet", |l| l.sample_id.as_str());
    let page = Page {
        film: &s.film,
        sample_id: id,
    };
    page.render()
        .unwrap_or_else(|e| format!("status page: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::line::{IndexMode, PassFail, ThicknessSummary};

    /// A failed sample of mean thickness `mean` nm, published after `latency_ms`.
    fn sample(mean: f64, latency_ms: f64) -> SampleRecord {
        SampleRecord {
            seq: None,
            sample_id: "S000001-20261125T230000Z".into(),
            counter: 1,
            timestamp: "2026-11-25T23:00:00.000Z".into(),
            film: "film".into(),
            recipe: "r.toml".into(),
            lot: None,
            operator: None,
            verdict: PassFail::of(false),
            reasons: vec!["mean thickness out".into()],
            refractive_index: None,
            index_mode: IndexMode::Hold,
            index_resolved: false,
            thickness_nm: ThicknessSummary {
                mean: Some(mean),
                std: Some(2.5),
                min: None,
                max: None,
            },
            valid_fraction: 0.75,
            out_of_tolerance_px: 0,
            regions: Vec::new(),
            raw_kept: false,
            folder: "samples/S000001".into(),
            latency_ms,
            version: "0".into(),
            sim_sample: None,
        }
    }

    /// The page's film and sample id are escaped for HTML (askama writes numeric character
    /// references); before a sample it says `none yet`.
    #[test]
    fn the_page_escapes_the_film_and_the_sample_id() {
        let board = StatusBoard::new("ZnS <i>\"AR\"</i> & co");
        let html = page(&board.lock());
        assert!(
            html.contains("<h1>ZnS &#60;i&#62;&#34;AR&#34;&#60;/i&#62; &#38; co</h1>"),
            "{html}"
        );
        assert!(html.contains("<b id=\"sample-id\">none yet</b>"), "{html}");
        let mut hostile = sample(620.0, 10.0);
        hostile.sample_id = "S1<script>alert(1)</script>".into();
        board.publish_sample(&hostile, None, Value::Null, &[]);
        let html = page(&board.lock());
        assert!(
            html.contains(">S1&#60;script&#62;alert(1)&#60;/script&#62;</b>"),
            "{html}"
        );
        assert_eq!(
            html.matches("<script>").count(),
            1,
            "only the page's own script"
        );
    }

    /// `/metrics` in the Prometheus text format: the labels escaped on every series, the
    /// counters' `# TYPE` under their `_total` names, the histogram cumulative with a
    /// latency beyond its last bound counted in `+Inf`, every sample line a name, labels and
    /// a number.
    #[test]
    fn metrics_are_prometheus_text() {
        let board = StatusBoard::new("film");
        board.set_labels("line\\7", "zns \"ar\"\n.toml");
        let history =
            serde_json::json!({"capability": {"thickness_mean_nm": {"cpk": 1.5, "ppk": 1.25}}});
        board.publish_sample(&sample(640.0, 12.5), None, history.clone(), &[]);
        board.publish_sample(&sample(612.25, 30_000.0), None, history, &[]);
        let m = metrics(&board.lock());
        let labels = r#"{line="line\\7",recipe="zns \"ar\"\n.toml""#;
        for line in [
            "# TYPE filmscope_latency_seconds histogram".to_owned(),
            "# HELP filmscope_samples_total Samples measured.".to_owned(),
            "# TYPE filmscope_samples_total counter".to_owned(),
            "# TYPE filmscope_last_pass gauge".to_owned(),
            format!("filmscope_latency_seconds_bucket{labels},le=\"0.01\"}} 0"),
            format!("filmscope_latency_seconds_bucket{labels},le=\"0.025\"}} 1"),
            format!("filmscope_latency_seconds_bucket{labels},le=\"10\"}} 1"),
            format!("filmscope_latency_seconds_bucket{labels},le=\"+Inf\"}} 2"),
            format!("filmscope_latency_seconds_sum{labels}}} 30.0125"),
            format!("filmscope_latency_seconds_count{labels}}} 2"),
            format!("filmscope_samples_total{labels}}} 2"),
            format!("filmscope_samples_failed_total{labels}}} 2"),
            format!("filmscope_samples_passed_total{labels}}} 0"),
            format!("filmscope_alarms_total{labels}}} 0"),
            format!("filmscope_last_pass{labels}}} 0"),
            format!("filmscope_last_refractive_index{labels}}} NaN"),
            format!("filmscope_last_thickness_mean_nm{labels}}} 612.25"),
            format!("filmscope_last_latency_seconds{labels}}} 30.0"),
            format!("filmscope_thickness_cpk{labels}}} 1.5"),
            format!("filmscope_thickness_ppk{labels}}} 1.25"),
        ] {
            assert!(m.lines().any(|l| l == line), "{line} in\n{m}");
        }
        assert!(!m.contains("# EOF") && !m.contains(".."), "{m}");
        for l in m.lines().filter(|l| !l.starts_with('#')) {
            let (series, value) = l.rsplit_once("} ").unwrap_or_else(|| panic!("{l}"));
            assert!(
                series.starts_with("filmscope_") && series.contains(labels),
                "{l}"
            );
            assert!(value.parse::<f64>().is_ok(), "{l}");
        }
        assert_eq!(
            m.lines().filter(|l| l.starts_with("# TYPE")).count(),
            14,
            "{m}"
        );
    }
}
