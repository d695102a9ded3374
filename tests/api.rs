//! The HTTP API end to end: every test starts the real server (axum + workers) on port 0 with
//! a fresh temporary database and data directory, and talks to it over HTTP.
//!
//! Two kinds of runner sit behind the queue:
//! - the real pipeline on simulated surveys (`roadmark simulate`), scored with the evaluator —
//!   the headline tests (`end_to_end_*`);
//! - small fake runners where the pipeline's accuracy is not the point: one that echoes its
//!   inputs, one that blocks at a gate until released (leases, cancellation, crash recovery,
//!   shutdown), one that fails transiently, one that rejects its input, one that panics.
//!
//! Time: the queue runs on a [`ManualClock`], so leases expire and retry delays pass when a
//! test says so, never by sleeping. Polling loops have deadlines and fail with the last state.

use roadmark::api::Application;
use roadmark::config::Config;
use roadmark::jobs::worker::{JobOutcome, run_once};
use roadmark::jobs::{JobStatus, ManualClock, PipelineRunner, Queue, Runner};
use roadmark::pipeline::params::ValidParams;
use roadmark::pipeline::{Extraction, Inputs, Marking, MarkingClass, PipelineError, Progress};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};
use tempfile::TempDir;
use tokio::sync::oneshot;
use tokio_util::sync::CancellationToken;

// =============================================================================================
// Harness
// =============================================================================================

struct TestApp {
    base: String,
    client: reqwest::Client,
    dir: Arc<TempDir>,
    clock: Arc<ManualClock>,
    config: Config,
    stop: Option<oneshot::Sender<()>>,
    handle: Option<tokio::task::JoinHandle<anyhow::Result<()>>>,
}

/// The shipped service: real pipeline, fresh directory.
async fn spawn_app() -> TestApp {
    spawn_with(Arc::new(PipelineRunner), None, None, |_| {}).await
}

/// The service with a given runner, optionally on an existing data directory and clock (a
/// restart), with config tweaks.
async fn spawn_with(
    runner: Arc<dyn Runner>,
    dir: Option<Arc<TempDir>>,
    clock: Option<Arc<ManualClock>>,
    tweak: impl FnOnce(&mut Config),
) -> TestApp {
    let dir = dir.unwrap_or_else(|| Arc::new(tempfile::tempdir().unwrap()));
    let clock = clock.unwrap_or_else(|| Arc::new(ManualClock::new()));
    let mut config = Config::for_tests(dir.path());
    tweak(&mut config);
    let app = Application::build_with(config.clone(), runner, clock.clone())
        .await
        .expect("the application builds");
    let base = format!("http://{}", app.local_addr());
    let (stop, stopped) = oneshot::channel::<()>();
    let handle = tokio::spawn(app.run_until_stopped(async {
        let _ = stopped.await;
    }));
    TestApp {
        base,
        client: reqwest::Client::new(),
        dir,
        clock,
        config,
        stop: Some(stop),
        handle: Some(handle),
    }
}

impl TestApp {
    fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    async fn upload(&self, bytes: Vec<u8>, filename: &str) -> reqwest::Response {
        self.client
            .post(self.url("/v1/uploads"))
            .query(&[("filename", filename)])
            .body(bytes)
            .send()
            .await
            .unwrap()
    }

    /// Upload and expect 201; returns the upload id.
    async fn upload_ok(&self, bytes: Vec<u8>, filename: &str) -> String {
        let r = self.upload(bytes, filename).await;
        let status = r.status();
        let body: Value = r.json().await.unwrap();
        assert_eq!(status, 201, "upload {filename}: {body}");
        body["id"].as_str().unwrap().to_string()
    }

    async fn post_job(&self, body: Value) -> reqwest::Response {
        self.client
            .post(self.url("/v1/jobs"))
            .json(&body)
            .send()
            .await
            .unwrap()
    }

    /// Create a job and expect 201; returns its id.
    async fn job_ok(&self, body: Value) -> String {
        let r = self.post_job(body).await;
        let status = r.status();
        let location = r
            .headers()
            .get("location")
            .map(|v| v.to_str().unwrap().to_string());
        let job: Value = r.json().await.unwrap();
        assert_eq!(status, 201, "{job}");
        let id = job["id"].as_str().unwrap().to_string();
        assert_eq!(location.as_deref(), Some(format!("/v1/jobs/{id}").as_str()));
        id
    }

    async fn get_json(&self, path: &str) -> (u16, Value) {
        let r = self.client.get(self.url(path)).send().await.unwrap();
        let status = r.status().as_u16();
        (status, r.json().await.unwrap_or(Value::Null))
    }

    async fn job(&self, id: &str) -> Value {
        let (status, body) = self.get_json(&format!("/v1/jobs/{id}")).await;
        assert_eq!(status, 200, "{body}");
        body
    }

    /// Poll the job until `done` holds (or fail after `timeout` with the last state).
    async fn wait_job(&self, id: &str, timeout: Duration, done: impl Fn(&Value) -> bool) -> Value {
        let deadline = Instant::now() + timeout;
        loop {
            let job = self.job(id).await;
            if done(&job) {
                return job;
            }
            assert!(
                Instant::now() < deadline,
                "job {id} did not get there in {timeout:?}: {job}"
            );
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    async fn wait_status(&self, id: &str, status: &str) -> Value {
        self.wait_job(id, Duration::from_secs(30), |j| j["status"] == status)
            .await
    }

    /// Wait until the job ended; returns it.
    async fn wait_finished(&self, id: &str, timeout: Duration) -> Value {
        self.wait_job(id, timeout, |j| {
            matches!(j["status"].as_str(), Some("succeeded" | "failed" | "cancelled"))
        })
        .await
    }

    async fn result(&self, id: &str, crs: Option<&str>) -> (u16, Value) {
        let path = match crs {
            Some(c) => format!("/v1/jobs/{id}/result?crs={c}"),
            None => format!("/v1/jobs/{id}/result"),
        };
        self.get_json(&path).await
    }

    /// Graceful stop (what SIGTERM does), waiting for the workers.
    async fn stop(mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(handle) = self.handle.take() {
            handle.await.unwrap().unwrap();
        }
    }

    /// Simulated crash: the server and workers vanish without any cleanup.
    async fn kill(mut self) {
        if let Some(handle) = self.handle.take() {
            handle.abort();
            let _ = handle.await;
        }
    }

    fn files_in(&self, sub: &str) -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(self.dir.path().join(sub))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        v.sort();
        v
    }

    async fn assert_healthy(&self) {
        let (status, body) = self.get_json("/healthz").await;
        assert_eq!(status, 200, "{body}");
        assert_eq!(body["status"], "ok");
    }
}

/// The database of a stopped service (a stopped service closes its own connections).
async fn open_queue(dir: &TempDir, clock: Arc<ManualClock>) -> Queue {
    let db = dir.path().join(roadmark::storage::DATABASE_FILE);
    Queue::connect(&db, clock).await.unwrap()
}

/// Expect a JSON error with this status and code; returns the message.
async fn expect_error(r: reqwest::Response, status: u16, code: &str) -> String {
    let got = r.status().as_u16();
    let text = r.text().await.unwrap();
    assert_eq!(got, status, "expected {status} {code}, got {got}: {text}");
    let body: Value = serde_json::from_str(&text).unwrap_or_else(|_| panic!("not JSON: {text}"));
    assert_eq!(body["error"]["code"], code, "{body}");
    let message = body["error"]["message"].as_str().unwrap().to_string();
    assert!(!message.is_empty());
    message
}

// =============================================================================================
// Test data
// =============================================================================================

/// A small LAS survey strip along +x (UTM-like coordinates, intensity, GPS time).
fn las_bytes(n: usize, compressed: bool) -> Vec<u8> {
    use las::{Builder, Point, Transform, Vector, Version, Writer, point::Format};
    let mut b = Builder::default();
    b.version = Version::new(1, 2);
    let mut format = Format::new(1).unwrap();
    format.is_compressed = compressed;
    b.point_format = format;
    b.transforms = Vector {
        x: Transform {
            scale: 0.001,
            offset: 231_000.0,
        },
        y: Transform {
            scale: 0.001,
            offset: 3_380_000.0,
        },
        z: Transform {
            scale: 0.001,
            offset: 0.0,
        },
    };
    let header = b.into_header().unwrap();
    let mut w = Writer::new(std::io::Cursor::new(Vec::new()), header).unwrap();
    for i in 0..n {
        let fi = i as f64;
        w.write_point(Point {
            x: 231_000.0 + (fi * 0.37) % 40.0,
            y: 3_380_000.0 + (fi * 0.11) % 8.0 - 4.0,
            z: 10.0,
            intensity: ((i * 977) % 60_000) as u16,
            gps_time: Some(1000.0 + fi * 1e-3),
            ..Default::default()
        })
        .unwrap();
    }
    w.into_inner().unwrap().into_inner()
}

/// A trajectory table along the strip: 10 m/s for `rows` seconds.
fn trajectory_csv(rows: usize) -> Vec<u8> {
    let mut s = String::from("time,x,y,z,heading\n");
    for i in 0..rows {
        let t = i as f64;
        s.push_str(&format!(
            "{},{:.3},{:.3},12.0,90.0\n",
            1000.0 + t,
            231_000.0 + 10.0 * t,
            3_380_000.0
        ));
    }
    s.into_bytes()
}

fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    hex::encode(Sha256::digest(bytes))
}

/// Upload one tile and one trajectory; returns (points id, trajectory id).
async fn upload_pair(app: &TestApp, tile_name: &str) -> (String, String) {
    let p = app.upload_ok(las_bytes(200, false), tile_name).await;
    let t = app.upload_ok(trajectory_csv(10), "trajectory.csv").await;
    (p, t)
}

// =============================================================================================
// Fake runners
// =============================================================================================

/// One marking per input tile, whose id is `<tag>:<upload file stem>`: a result shows which
/// inputs and which runner produced it.
fn echo_extraction(tag: &str, inputs: &Inputs) -> Extraction {
    let markings = inputs
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let x = 231_000.0 + 5.0 * i as f64;
            Marking {
                id: format!("{tag}:{}", p.file_stem().unwrap().to_string_lossy()),
                class: MarkingClass::DashedLine,
                outline: vec![
                    [x, 3_380_000.0],
                    [x + 3.0, 3_380_000.0],
                    [x + 3.0, 3_380_000.15],
                    [x, 3_380_000.15],
                ],
                confidence: 0.9,
                length_m: 3.0,
                width_m: 0.15,
                heading_deg: 90.0,
                point_count: 10,
            }
        })
        .collect();
    Extraction {
        markings,
        lane_lines: vec![],
        crs: None,
    }
}

/// Upload id behind each marking of an echo result.
fn echoed_uploads(result: &Value) -> Vec<String> {
    let mut ids: Vec<String> = result["features"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            f["properties"]["id"]
                .as_str()
                .unwrap()
                .split(':')
                .nth(1)
                .unwrap()
                .to_string()
        })
        .collect();
    ids.sort();
    ids
}

/// Reports progress, optionally takes its time, echoes its inputs; counts concurrency.
#[derive(Default)]
struct EchoRunner {
    tag: &'static str,
    delay: Duration,
    runs: AtomicUsize,
    active: AtomicUsize,
    max_active: AtomicUsize,
}

impl EchoRunner {
    fn new(tag: &'static str) -> Arc<EchoRunner> {
        Arc::new(EchoRunner {
            tag,
            ..Default::default()
        })
    }
}

impl Runner for EchoRunner {
    fn run(
        &self,
        inputs: &Inputs,
        _: &ValidParams,
        progress: &dyn Progress,
    ) -> Result<Extraction, PipelineError> {
        self.runs.fetch_add(1, Ordering::SeqCst);
        let now = self.active.fetch_add(1, Ordering::SeqCst) + 1;
        self.max_active.fetch_max(now, Ordering::SeqCst);
        progress.report("echo", 0.5);
        std::thread::sleep(self.delay);
        self.active.fetch_sub(1, Ordering::SeqCst);
        if progress.is_cancelled() {
            return Err(PipelineError::Cancelled);
        }
        Ok(echo_extraction(self.tag, inputs))
    }
}

/// Blocks at a gate until [`GateRunner::open`] (or, if it honours cancellation, until asked to
/// stop — as the real pipeline does at a stage boundary).
struct GateRunner {
    tag: &'static str,
    honour_cancel: bool,
    open: Mutex<bool>,
    cv: Condvar,
    started: AtomicUsize,
    returned: AtomicUsize,
}

impl GateRunner {
    fn new(tag: &'static str, honour_cancel: bool) -> Arc<GateRunner> {
        Arc::new(GateRunner {
            tag,
            honour_cancel,
            open: Mutex::new(false),
            cv: Condvar::new(),
            started: AtomicUsize::new(0),
            returned: AtomicUsize::new(0),
        })
    }

    fn release(&self) {
        *self.open.lock().unwrap() = true;
        self.cv.notify_all();
    }
}

impl Runner for GateRunner {
    fn run(
        &self,
        inputs: &Inputs,
        _: &ValidParams,
        progress: &dyn Progress,
    ) -> Result<Extraction, PipelineError> {
        self.started.fetch_add(1, Ordering::SeqCst);
        progress.report("at-the-gate", 0.25);
        let mut open = self.open.lock().unwrap();
        while !*open {
            if self.honour_cancel && progress.is_cancelled() {
                self.returned.fetch_add(1, Ordering::SeqCst);
                return Err(PipelineError::Cancelled);
            }
            open = self.cv.wait_timeout(open, Duration::from_millis(5)).unwrap().0;
        }
        self.returned.fetch_add(1, Ordering::SeqCst);
        Ok(echo_extraction(self.tag, inputs))
    }
}

/// Poll `done` every 5 ms; panics naming `what` after 30 s.
async fn wait_until(what: &str, done: impl Fn() -> bool) {
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    while !done() {
        assert!(
            std::time::Instant::now() < deadline,
            "timed out waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

/// Fails with a transient I/O error the first `failures` times, then succeeds.
struct FlakyRunner {
    failures: usize,
    calls: AtomicUsize,
}

impl Runner for FlakyRunner {
    fn run(&self, inputs: &Inputs, _: &ValidParams, _: &dyn Progress) -> Result<Extraction, PipelineError> {
        if self.calls.fetch_add(1, Ordering::SeqCst) < self.failures {
            return Err(PipelineError::Io {
                path: inputs.points[0].clone(),
                source: std::io::Error::other("device temporarily unavailable"),
            });
        }
        Ok(echo_extraction("flaky", inputs))
    }
}

/// Rejects its first tile as bad input (fatal) — or panics.
struct BrokenRunner {
    panic: bool,
}

impl Runner for BrokenRunner {
    fn run(&self, inputs: &Inputs, _: &ValidParams, _: &dyn Progress) -> Result<Extraction, PipelineError> {
        assert!(!self.panic, "index out of bounds in a stage");
        Err(PipelineError::input(
            &inputs.points[0],
            "no intensity values in any point",
        ))
    }
}

// =============================================================================================
// Service basics
// =============================================================================================

#[tokio::test]
async fn health_openapi_and_json_fallbacks() {
    let app = spawn_with(EchoRunner::new("e"), None, None, |_| {}).await;
    app.assert_healthy().await;

    // The served document is the generated one, and it is the one committed in openapi/.
    let served = app
        .client
        .get(app.url("/openapi.json"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert_eq!(served, roadmark::api::openapi_json());
    let doc: Value = serde_json::from_str(&served).unwrap();
    for path in [
        "/v1/uploads",
        "/v1/jobs",
        "/v1/jobs/{id}",
        "/v1/jobs/{id}/result",
        "/healthz",
    ] {
        assert!(
            doc["paths"][path].is_object(),
            "{path} missing from the OpenAPI document"
        );
    }

    let r = app.client.get(app.url("/v2/nothing")).send().await.unwrap();
    expect_error(r, 404, "not-found").await;
    let r = app.client.put(app.url("/v1/jobs")).send().await.unwrap();
    expect_error(r, 405, "method-not-allowed").await;
    app.stop().await;
}

/// `openapi/openapi.json` is pinned: the test fails with a diff when the code's document
/// differs. `UPDATE_OPENAPI=1 cargo test --test api openapi_snapshot` rewrites it.
#[test]
fn openapi_snapshot() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("openapi/openapi.json");
    let generated = roadmark::api::openapi_json();
    if std::env::var_os("UPDATE_OPENAPI").is_some() {
        std::fs::write(&path, &generated).unwrap();
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    if committed != generated {
        let diff: Vec<String> = committed
            .lines()
            .zip(generated.lines())
            .enumerate()
            .filter(|(_, (a, b))| a != b)
            .take(20)
            .map(|(i, (a, b))| format!("line {}:\n  committed: {a}\n  generated: {b}", i + 1))
            .collect();
        panic!(
            "openapi/openapi.json is out of date ({} vs {} lines); run `UPDATE_OPENAPI=1 cargo test --test api \
             openapi_snapshot` and commit it.\n{}",
            committed.lines().count(),
            generated.lines().count(),
            diff.join("\n")
        );
    }
}

// =============================================================================================
// Uploads
// =============================================================================================

#[tokio::test]
async fn uploads_are_streamed_hashed_and_summarised() {
    let app = spawn_with(EchoRunner::new("e"), None, None, |_| {}).await;

    let las = las_bytes(500, false);
    let r = app.upload(las.clone(), "../../strip.las").await;
    assert_eq!(r.status(), 201);
    let location = r.headers()["location"].to_str().unwrap().to_string();
    let up: Value = r.json().await.unwrap();
    assert_eq!(up["kind"], "las");
    assert_eq!(up["filename"], "strip.las", "path components are dropped");
    assert_eq!(up["size"], las.len());
    assert_eq!(up["sha256"], sha256_hex(&las));
    assert_eq!(up["summary"]["point_count"], 500);
    assert_eq!(up["summary"]["point_format"], 1);
    assert_eq!(up["summary"]["has_gps_time"], true);
    let min_x = up["summary"]["bounds"][0][0].as_f64().unwrap();
    assert!((min_x - 231_000.0).abs() < 0.01, "{up}");
    let (status, again) = app.get_json(&location).await;
    assert_eq!(status, 200);
    assert_eq!(again["sha256"], up["sha256"]);

    let laz = las_bytes(500, true);
    let r = app.upload(laz.clone(), "strip.laz").await;
    let up: Value = r.json().await.unwrap();
    assert_eq!(up["kind"], "laz", "{up}");
    assert_eq!(up["summary"]["compressed"], true);
    assert_eq!(up["summary"]["point_count"], 500);

    let csv = trajectory_csv(12);
    let r = app.upload(csv.clone(), "trajectory.csv").await;
    let up: Value = r.json().await.unwrap();
    assert_eq!(up["kind"], "trajectory", "{up}");
    assert_eq!(up["summary"]["rows"], 12);
    assert!(
        (up["summary"]["length_m"].as_f64().unwrap() - 110.0).abs() < 1e-6,
        "{up}"
    );

    // Server-chosen names only; nothing left in tmp/.
    assert_eq!(app.files_in("uploads").len(), 3);
    assert!(app.files_in("tmp").is_empty());
    let r = app.client.get(app.url("/v1/uploads/nope")).send().await.unwrap();
    expect_error(r, 404, "upload-not-found").await;
    app.stop().await;
}

#[tokio::test]
async fn bad_uploads_get_clear_errors_and_nothing_else_is_affected() {
    let gate = GateRunner::new("g", false);
    let app = spawn_with(gate.clone(), None, None, |c| c.max_upload_bytes = 64 * 1024).await;

    // A job is running while the bad requests come in.
    let (p, t) = upload_pair(&app, "good.las").await;
    let running = app.job_ok(json!({"points": [p], "trajectory": t})).await;
    app.wait_status(&running, "running").await;

    // Not LAS, not a trajectory.
    let m = expect_error(
        app.upload(b"\x89PNG\r\n\x1a\n binary junk".to_vec(), "photo.png")
            .await,
        415,
        "unsupported-file",
    )
    .await;
    assert!(m.contains("photo.png"), "{m}");
    expect_error(
        app.upload(b"hello, world\nthis is prose\n".to_vec(), "notes.txt")
            .await,
        415,
        "unsupported-file",
    )
    .await;
    // Truncated LAS: the header promises more points than the file holds.
    let las = las_bytes(1000, false);
    let m = expect_error(
        app.upload(las[..las.len() * 2 / 3].to_vec(), "cut.las").await,
        422,
        "invalid-file",
    )
    .await;
    assert!(m.contains("cut.las"), "{m}");
    // Only the header.
    expect_error(
        app.upload(las[..227].to_vec(), "header-only.las").await,
        422,
        "invalid-file",
    )
    .await;
    // Empty body.
    expect_error(app.upload(Vec::new(), "empty.las").await, 400, "empty-body").await;
    // A trajectory table without rows, and one with a malformed row.
    let m = expect_error(
        app.upload(b"time,x,y\n".to_vec(), "empty.csv").await,
        422,
        "invalid-file",
    )
    .await;
    assert!(m.contains("empty.csv"), "{m}");
    let m = expect_error(
        app.upload(
            b"time,x,y\n1,231000,3380000\n2,abc,3380000\n3,231020,3380000\n".to_vec(),
            "bad.csv",
        )
        .await,
        422,
        "invalid-file",
    )
    .await;
    assert!(m.contains("bad.csv"), "{m}");
    // Too large: announced by Content-Length, and streamed without it (chunked).
    let big = las_bytes(5000, false);
    assert!(big.len() > 64 * 1024);
    let m = expect_error(app.upload(big.clone(), "big.las").await, 413, "payload-too-large").await;
    assert!(m.contains("65536"), "{m}");
    let chunks: Vec<Result<Vec<u8>, std::io::Error>> = big.chunks(8192).map(|c| Ok(c.to_vec())).collect();
    let r = app
        .client
        .post(app.url("/v1/uploads"))
        .body(reqwest::Body::wrap_stream(futures_util::stream::iter(chunks)))
        .send()
        .await
        .unwrap();
    expect_error(r, 413, "payload-too-large").await;

    // A form upload (curl -F) to the raw-body endpoint gets a hint instead of a stored envelope.
    let form =
        reqwest::multipart::Form::new().part("file", reqwest::multipart::Part::bytes(las_bytes(10, false)));
    let r = app
        .client
        .post(app.url("/v1/uploads"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    let m = expect_error(r, 415, "unsupported-media-type").await;
    assert!(m.contains("--data-binary"), "{m}");

    // No partial file survives; only the two good uploads are stored.
    assert!(app.files_in("tmp").is_empty(), "{:?}", app.files_in("tmp"));
    assert_eq!(app.files_in("uploads").len(), 2);

    // The server keeps serving and the running job is unaffected.
    app.assert_healthy().await;
    gate.release();
    let job = app.wait_finished(&running, Duration::from_secs(30)).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    app.stop().await;
}

// =============================================================================================
// Jobs: validation
// =============================================================================================

#[tokio::test]
async fn bad_job_requests_are_rejected_before_enqueue() {
    let app = spawn_with(EchoRunner::new("e"), None, None, |_| {}).await;
    let (p, t) = upload_pair(&app, "tile.las").await;

    let m = expect_error(
        app.post_job(json!({"points": ["no-such-upload"], "trajectory": t}))
            .await,
        422,
        "unknown-upload",
    )
    .await;
    assert!(m.contains("no-such-upload"), "{m}");
    expect_error(
        app.post_job(json!({"points": [p], "trajectory": "missing"}))
            .await,
        422,
        "unknown-upload",
    )
    .await;
    expect_error(
        app.post_job(json!({"points": [t], "trajectory": t})).await,
        422,
        "wrong-upload-kind",
    )
    .await;
    expect_error(
        app.post_job(json!({"points": [p], "trajectory": p})).await,
        422,
        "wrong-upload-kind",
    )
    .await;
    expect_error(
        app.post_job(json!({"points": [], "trajectory": t})).await,
        422,
        "unprocessable",
    )
    .await;
    expect_error(
        app.post_job(json!({"points": [p, p], "trajectory": t})).await,
        422,
        "unprocessable",
    )
    .await;
    expect_error(app.post_job(json!({"points": [p]})).await, 422, "unprocessable").await;
    expect_error(
        app.post_job(json!({"points": [p], "trajectory": t, "extra": 1}))
            .await,
        422,
        "unprocessable",
    )
    .await;

    // Parameters: unknown names and absurd values, named in the message.
    let m = expect_error(
        app.post_job(json!({"points": [p], "trajectory": t, "params": {"rasterise": {}}}))
            .await,
        422,
        "invalid-params",
    )
    .await;
    assert!(m.contains("rasterise"), "{m}");
    let m = expect_error(
        app.post_job(json!({"points": [p], "trajectory": t, "params": {"rasterize": {"cell_size_m": -1.0}}}))
            .await,
        422,
        "invalid-params",
    )
    .await;
    assert!(m.contains("cell_size_m"), "{m}");
    expect_error(
        app.post_job(json!({"points": [p], "trajectory": t, "params": "fast please"}))
            .await,
        422,
        "invalid-params",
    )
    .await;

    // Syntax and content type.
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("content-type", "application/json")
        .body("{\"points\": [")
        .send()
        .await
        .unwrap();
    expect_error(r, 400, "bad-request").await;
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("content-type", "text/plain")
        .body("points")
        .send()
        .await
        .unwrap();
    expect_error(r, 415, "unsupported-media-type").await;

    // Unknown jobs.
    expect_error(
        app.client.get(app.url("/v1/jobs/nope")).send().await.unwrap(),
        404,
        "job-not-found",
    )
    .await;
    expect_error(
        app.client
            .get(app.url("/v1/jobs/nope/result"))
            .send()
            .await
            .unwrap(),
        404,
        "job-not-found",
    )
    .await;
    expect_error(
        app.client.delete(app.url("/v1/jobs/nope")).send().await.unwrap(),
        404,
        "job-not-found",
    )
    .await;
    expect_error(
        app.client.get(app.url("/v1/jobs?limit=0")).send().await.unwrap(),
        400,
        "bad-request",
    )
    .await;
    expect_error(
        app.client
            .get(app.url("/v1/jobs?cursor=abc"))
            .send()
            .await
            .unwrap(),
        400,
        "bad-request",
    )
    .await;
    expect_error(
        app.client
            .get(app.url("/v1/jobs?status=bogus"))
            .send()
            .await
            .unwrap(),
        400,
        "bad-request",
    )
    .await;

    expect_error(
        app.client.get(app.url("/v1/jobs/%FF%FE")).send().await.unwrap(),
        400,
        "bad-request",
    )
    .await;

    // Nothing was enqueued by any of these.
    let (_, page) = app.get_json("/v1/jobs").await;
    assert_eq!(page["jobs"].as_array().unwrap().len(), 0, "{page}");
    app.stop().await;
}

// =============================================================================================
// Jobs: life cycle (fake runners)
// =============================================================================================

#[tokio::test]
async fn job_runs_to_success_with_progress_result_and_links() {
    let gate = GateRunner::new("g", false);
    let app = spawn_with(gate.clone(), None, None, |_| {}).await;
    let (p, t) = upload_pair(&app, "tile.las").await;
    let id = app
        .job_ok(json!({"points": [p], "trajectory": t, "params": {"rasterize": {}}}))
        .await;

    // While it runs: progress is visible, the result is not there yet.
    let job = app
        .wait_job(&id, Duration::from_secs(30), |j| {
            j["progress"]["stage"] == "at-the-gate"
        })
        .await;
    assert_eq!(job["status"], "running");
    assert_eq!(job["attempts"], 1);
    assert_eq!(job["progress"]["fraction"], 0.25);
    assert!(job["started_at"].is_string());
    assert_eq!(job["inputs"]["points"], json!([p]));
    assert_eq!(job["inputs"]["trajectory"], t);
    // Resolved parameters: every stage present, defaults filled in.
    for stage in [
        "pavement",
        "rasterize",
        "threshold",
        "cluster",
        "classify",
        "vectorize",
        "learned",
    ] {
        assert!(
            job["params"][stage].is_object(),
            "{stage} missing: {}",
            job["params"]
        );
    }
    let (status, body) = app.result(&id, None).await;
    assert_eq!(status, 409, "{body}");
    assert_eq!(body["error"]["code"], "job-not-finished");

    gate.release();
    let job = app.wait_finished(&id, Duration::from_secs(30)).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(job["progress"]["stage"], "done");
    assert_eq!(job["progress"]["fraction"], 1.0);
    assert!(job["finished_at"].is_string());
    assert!(job["error"].is_null());
    assert_eq!(job["links"]["self"], format!("/v1/jobs/{id}"));
    assert_eq!(job["links"]["result"], format!("/v1/jobs/{id}/result"));

    // The echo result has no CRS: native by default, WGS84 impossible.
    let (status, fc) = app.result(&id, None).await;
    assert_eq!(status, 200, "{fc}");
    assert_eq!(fc["type"], "FeatureCollection");
    assert_eq!(echoed_uploads(&fc), vec![p.clone()]);
    let (status, native) = app.result(&id, Some("native")).await;
    assert_eq!((status, &native), (200, &fc));
    let (status, body) = app.result(&id, Some("wgs84")).await;
    assert_eq!(status, 422, "{body}");
    assert_eq!(body["error"]["code"], "crs-unknown");
    let (status, body) = app.result(&id, Some("mercator")).await;
    assert_eq!(status, 400, "{body}");
    app.stop().await;
}

#[tokio::test]
async fn listing_is_newest_first_with_a_cursor() {
    let app = spawn_with(EchoRunner::new("e"), None, None, |_| {}).await;
    let (p, t) = upload_pair(&app, "tile.las").await;
    let mut ids = Vec::new();
    for _ in 0..5 {
        ids.push(app.job_ok(json!({"points": [p], "trajectory": t})).await);
    }
    let (_, first) = app.get_json("/v1/jobs?limit=2").await;
    let got: Vec<&str> = first["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["id"].as_str().unwrap())
        .collect();
    assert_eq!(got, vec![ids[4].as_str(), ids[3].as_str()]);
    let cursor = first["next_cursor"].as_str().unwrap();
    let (_, second) = app.get_json(&format!("/v1/jobs?limit=2&cursor={cursor}")).await;
    let got: Vec<&str> = second["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["id"].as_str().unwrap())
        .collect();
    assert_eq!(got, vec![ids[2].as_str(), ids[1].as_str()]);
    let cursor = second["next_cursor"].as_str().unwrap();
    let (_, last) = app.get_json(&format!("/v1/jobs?limit=2&cursor={cursor}")).await;
    assert_eq!(last["jobs"].as_array().unwrap().len(), 1);
    assert!(last["next_cursor"].is_null());

    for id in &ids {
        app.wait_status(id, "succeeded").await;
    }
    let (_, done) = app.get_json("/v1/jobs?status=succeeded&limit=100").await;
    assert_eq!(done["jobs"].as_array().unwrap().len(), 5);
    app.stop().await;
}

#[tokio::test]
async fn cancel_queued_at_once_and_running_at_the_next_stage_boundary() {
    let gate = GateRunner::new("g", true);
    let app = spawn_with(gate.clone(), None, None, |c| c.workers = 1).await;
    let (p, t) = upload_pair(&app, "tile.las").await;
    let a = app.job_ok(json!({"points": [p], "trajectory": t})).await;
    app.wait_status(&a, "running").await;
    let b = app.job_ok(json!({"points": [p], "trajectory": t})).await;

    // Queued: cancelled at once.
    let r = app
        .client
        .delete(app.url(&format!("/v1/jobs/{b}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let body: Value = r.json().await.unwrap();
    assert_eq!(body["status"], "cancelled");
    // Running: asked to stop; the worker sees it with its next heartbeat.
    let r = app
        .client
        .delete(app.url(&format!("/v1/jobs/{a}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 202);
    let body: Value = r.json().await.unwrap();
    assert_eq!(
        (body["status"].as_str(), body["cancel_requested"].as_bool()),
        (Some("running"), Some(true))
    );
    let job = app.wait_finished(&a, Duration::from_secs(30)).await;
    assert_eq!(job["status"], "cancelled", "{job}");
    assert_eq!(
        gate.started.load(Ordering::SeqCst),
        1,
        "the cancelled queued job never ran"
    );

    // Cancelling again is harmless; a cancelled job has no result.
    let r = app
        .client
        .delete(app.url(&format!("/v1/jobs/{a}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let (status, body) = app.result(&a, None).await;
    assert_eq!(
        (status, body["error"]["code"].as_str()),
        (409, Some("job-not-finished"))
    );

    // The worker is free again; a finished job cannot be cancelled.
    gate.release();
    let c = app.job_ok(json!({"points": [p], "trajectory": t})).await;
    assert_eq!(
        app.wait_finished(&c, Duration::from_secs(30)).await["status"],
        "succeeded"
    );
    let r = app
        .client
        .delete(app.url(&format!("/v1/jobs/{c}")))
        .send()
        .await
        .unwrap();
    expect_error(r, 409, "job-already-finished").await;
    app.stop().await;
}

#[tokio::test]
async fn transient_failures_are_retried_with_backoff_bad_input_is_not() {
    let flaky = Arc::new(FlakyRunner {
        failures: 2,
        calls: AtomicUsize::new(0),
    });
    let app = spawn_with(flaky.clone(), None, None, |c| c.workers = 1).await;
    let (p, t) = upload_pair(&app, "tile.las").await;
    let id = app.job_ok(json!({"points": [p], "trajectory": t})).await;
    // Each failure puts the job back with a delay on the queue's clock: let time pass.
    let deadline = Instant::now() + Duration::from_secs(30);
    let job = loop {
        let job = app.job(&id).await;
        if job["status"] == "succeeded" || job["status"] == "failed" {
            break job;
        }
        if job["status"] == "queued" && job["attempts"].as_i64() > Some(0) {
            assert_eq!(
                job["error"]["code"], "io-error",
                "the last error stays visible: {job}"
            );
            assert_eq!(job["progress"]["stage"], "retry-wait");
            app.clock.advance(app.config.retry_max_ms as i64);
        }
        assert!(Instant::now() < deadline, "{job}");
        tokio::time::sleep(Duration::from_millis(5)).await;
    };
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(job["attempts"], 3);
    assert_eq!(flaky.calls.load(Ordering::SeqCst), 3);
    app.stop().await;

    // Out of attempts: failed, saying so.
    let flaky = Arc::new(FlakyRunner {
        failures: 100,
        calls: AtomicUsize::new(0),
    });
    let app = spawn_with(flaky.clone(), None, None, |c| c.workers = 1).await;
    let (p, t) = upload_pair(&app, "tile.las").await;
    let id = app.job_ok(json!({"points": [p], "trajectory": t})).await;
    let deadline = Instant::now() + Duration::from_secs(30);
    let job = loop {
        let job = app.job(&id).await;
        if job["status"] == "failed" {
            break job;
        }
        app.clock.advance(app.config.retry_max_ms as i64);
        assert!(Instant::now() < deadline, "{job}");
        tokio::time::sleep(Duration::from_millis(5)).await;
    };
    assert_eq!(job["attempts"], 3);
    assert_eq!(job["error"]["code"], "io-error");
    let message = job["error"]["message"].as_str().unwrap();
    assert!(message.contains("gave up after 3 attempts"), "{message}");
    assert_eq!(flaky.calls.load(Ordering::SeqCst), 3);
    app.stop().await;

    // Bad input: failed at the first attempt, the message names the upload, not a server path.
    let app = spawn_with(Arc::new(BrokenRunner { panic: false }), None, None, |_| {}).await;
    let (p, t) = upload_pair(&app, "tile-07.las").await;
    let id = app.job_ok(json!({"points": [p], "trajectory": t})).await;
    let job = app.wait_finished(&id, Duration::from_secs(30)).await;
    assert_eq!(job["status"], "failed");
    assert_eq!(job["attempts"], 1);
    assert_eq!(job["error"]["code"], "invalid-input");
    let message = job["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("tile-07.las") && message.contains(&p),
        "{message}"
    );
    assert!(!message.contains(app.dir.path().to_str().unwrap()), "{message}");
    app.stop().await;
}

#[tokio::test]
async fn a_panicking_pipeline_fails_its_job_and_the_service_carries_on() {
    let app = spawn_with(Arc::new(BrokenRunner { panic: true }), None, None, |_| {}).await;
    let (p, t) = upload_pair(&app, "tile.las").await;
    let id = app.job_ok(json!({"points": [p], "trajectory": t})).await;
    let job = app.wait_finished(&id, Duration::from_secs(30)).await;
    assert_eq!(job["status"], "failed");
    assert_eq!(job["error"]["code"], "internal-error");
    assert!(
        job["error"]["message"]
            .as_str()
            .unwrap()
            .contains("index out of bounds"),
        "{job}"
    );
    // The pool thread survived: the next job runs (and fails the same way) too.
    let id = app.job_ok(json!({"points": [p], "trajectory": t})).await;
    assert_eq!(
        app.wait_finished(&id, Duration::from_secs(30)).await["status"],
        "failed"
    );
    app.assert_healthy().await;
    app.stop().await;
}

#[tokio::test]
async fn several_jobs_run_at_once_and_each_gets_its_own_result() {
    let runner = Arc::new(EchoRunner {
        tag: "c",
        delay: Duration::from_millis(300),
        ..Default::default()
    });
    let app = spawn_with(runner.clone(), None, None, |c| {
        c.workers = 3;
        c.threads = 3;
    })
    .await;
    let t = app.upload_ok(trajectory_csv(10), "trajectory.csv").await;
    let mut tiles = Vec::new();
    for i in 0..6 {
        let a = app
            .upload_ok(las_bytes(100 + i, false), &format!("a{i}.las"))
            .await;
        let b = app
            .upload_ok(las_bytes(200 + i, false), &format!("b{i}.las"))
            .await;
        tiles.push(vec![a, b]);
    }
    let creates = tiles
        .iter()
        .map(|points| app.job_ok(json!({"points": points, "trajectory": t})));
    let ids: Vec<String> = futures_util::future::join_all(creates).await;
    for (id, points) in ids.iter().zip(&tiles) {
        let job = app.wait_finished(id, Duration::from_secs(60)).await;
        assert_eq!(job["status"], "succeeded", "{job}");
        let (status, fc) = app.result(id, None).await;
        assert_eq!(status, 200);
        let mut expected = points.clone();
        expected.sort();
        assert_eq!(echoed_uploads(&fc), expected, "job {id} got another job's result");
    }
    assert_eq!(runner.runs.load(Ordering::SeqCst), 6, "each job ran exactly once");
    assert!(
        runner.max_active.load(Ordering::SeqCst) >= 2,
        "jobs did not overlap"
    );
    assert_eq!(app.files_in("results").len(), 6);
    app.stop().await;
}

#[tokio::test]
async fn multipart_jobs_carry_their_files_inline() {
    let app = spawn_with(EchoRunner::new("m"), None, None, |_| {}).await;
    let part =
        |bytes: Vec<u8>, name: &str| reqwest::multipart::Part::bytes(bytes).file_name(name.to_string());
    let form = reqwest::multipart::Form::new()
        .part("points", part(las_bytes(300, false), "west.las"))
        .part("points", part(las_bytes(300, true), "east.laz"))
        .part("trajectory", part(trajectory_csv(10), "trajectory.csv"))
        .text("params", json!({"cluster": {}}).to_string());
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let job: Value = r.json().await.unwrap();
    let id = job["id"].as_str().unwrap();
    let points: Vec<String> = job["inputs"]["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_string())
        .collect();
    assert_eq!(points.len(), 2);
    let (_, west) = app.get_json(&format!("/v1/uploads/{}", points[0])).await;
    assert_eq!(
        (west["filename"].as_str(), west["kind"].as_str()),
        (Some("west.las"), Some("las"))
    );
    assert_eq!(
        app.wait_finished(id, Duration::from_secs(30)).await["status"],
        "succeeded"
    );
    let (_, fc) = app.result(id, None).await;
    let mut expected = points.clone();
    expected.sort();
    assert_eq!(echoed_uploads(&fc), expected);

    // Failures remove the files this request brought.
    let before = app.files_in("uploads").len();
    let form = reqwest::multipart::Form::new()
        .part("points", part(las_bytes(300, false), "west.las"))
        .part("trajectory", part(trajectory_csv(10), "trajectory.csv"))
        .text("params", json!({"cluster": {"no_such_option": 3}}).to_string());
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    expect_error(r, 422, "invalid-params").await;
    let form = reqwest::multipart::Form::new()
        .part("points", part(las_bytes(300, false), "west.las"))
        .part("trajectory", part(las_bytes(300, false), "oops.las"));
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    let m = expect_error(r, 422, "wrong-upload-kind").await;
    assert!(m.contains("oops.las"), "{m}");
    let form = reqwest::multipart::Form::new().part("points", part(las_bytes(300, false), "west.las"));
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    expect_error(r, 422, "unprocessable").await;
    let form = reqwest::multipart::Form::new()
        .part("points", part(las_bytes(300, false)[..500].to_vec(), "cut.las"))
        .part("trajectory", part(trajectory_csv(10), "trajectory.csv"));
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    expect_error(r, 422, "invalid-file").await;
    let form = reqwest::multipart::Form::new().text("surprise", "x");
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    expect_error(r, 400, "bad-request").await;
    assert_eq!(app.files_in("uploads").len(), before);
    assert!(app.files_in("tmp").is_empty());
    app.stop().await;
}

// =============================================================================================
// Crash recovery, fencing, graceful shutdown
// =============================================================================================

#[tokio::test]
async fn a_crashed_worker_s_job_completes_exactly_once_after_restart() {
    let stuck = GateRunner::new("crashed", false);
    let first = spawn_with(stuck.clone(), None, None, |_| {}).await;
    let (p, t) = upload_pair(&first, "tile.las").await;
    let id = first.job_ok(json!({"points": [p], "trajectory": t})).await;
    first.wait_status(&id, "running").await;
    // The job is marked running when it is claimed, a moment before its pipeline starts:
    // crash only once the pipeline runs (killed before, it never starts, and never returns
    // below).
    wait_until("the crashed worker's pipeline to start", || {
        stuck.started.load(Ordering::SeqCst) > 0
    })
    .await;
    let (dir, clock, lease_ms) = (
        first.dir.clone(),
        first.clock.clone(),
        first.config.lease_ms as i64,
    );
    first.kill().await;

    // Restart on the same data directory. The dead worker's lease still holds...
    let runner = EchoRunner::new("restarted");
    let config = Config::for_tests(dir.path());
    let second = Application::build_with(config, runner.clone(), clock.clone())
        .await
        .unwrap();
    let ctx = second.worker_context();
    let token = CancellationToken::new();
    assert_eq!(
        run_once(&ctx, "probe", &token).await.unwrap(),
        None,
        "lease still held"
    );
    // ...until it expires; then the job is claimed again and completes.
    clock.advance(lease_ms + 1);
    let (claimed, outcome) = run_once(&ctx, "probe", &token).await.unwrap().unwrap();
    assert_eq!((claimed.as_str(), outcome), (id.as_str(), JobOutcome::Succeeded));
    assert_eq!(
        run_once(&ctx, "probe", &token).await.unwrap(),
        None,
        "nothing else to do"
    );

    // Serve it and check: succeeded once, the second attempt's result, one result file.
    let second = spawn_with(runner.clone(), Some(dir.clone()), Some(clock.clone()), |_| {}).await;
    let job = second.job(&id).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(job["attempts"], 2);
    let (_, fc) = second.result(&id, None).await;
    let ids: Vec<&str> = fc["features"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["properties"]["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, vec![format!("restarted:{p}")]);
    assert_eq!(second.files_in("results").len(), 1);
    assert_eq!(runner.runs.load(Ordering::SeqCst), 1);

    // The crashed process's pipeline finally returns: its answer has nowhere to go.
    stuck.release();
    wait_until("the crashed worker's pipeline to return", || {
        stuck.returned.load(Ordering::SeqCst) > 0
    })
    .await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(second.files_in("results").len(), 1);
    assert_eq!(second.job(&id).await["attempts"], 2);
    second.stop().await;
}

#[tokio::test]
async fn a_stale_worker_cannot_overwrite_the_job_after_losing_its_lease() {
    // A worker that stalls without dying: no heartbeat within the test's time (30 s period).
    let slow = GateRunner::new("stale", false);
    let first = spawn_with(slow.clone(), None, None, |c| {
        c.lease_ms = 60_000;
        c.heartbeat_ms = 30_000;
        c.workers = 1;
    })
    .await;
    let (p, t) = upload_pair(&first, "tile.las").await;
    let id = first.job_ok(json!({"points": [p], "trajectory": t})).await;
    first.wait_status(&id, "running").await;

    // Its lease expires; another process takes the job over and finishes it.
    first.clock.advance(60_001);
    let other = Application::build_with(
        Config::for_tests(first.dir.path()),
        EchoRunner::new("fresh"),
        first.clock.clone(),
    )
    .await
    .unwrap();
    let token = CancellationToken::new();
    let (_, outcome) = run_once(&other.worker_context(), "other", &token)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(outcome, JobOutcome::Succeeded);

    // Now the stale worker's pipeline returns and it tries to store its result: fenced out.
    slow.release();
    let (clock, dir) = (first.clock.clone(), first.dir.clone());
    first.stop().await; // waits for the stale worker to finish handling its outcome
    let job = open_queue(&dir, clock).await.get(&id).await.unwrap().unwrap();
    assert_eq!(job.status, JobStatus::Succeeded);
    assert_eq!(job.attempts, 2);
    let results: Vec<_> = std::fs::read_dir(dir.path().join("results")).unwrap().collect();
    assert_eq!(results.len(), 1, "the stale worker's file was removed");
    let served = spawn_with(EchoRunner::new("x"), Some(dir), None, |_| {}).await;
    let (_, fc) = served.result(&id, None).await;
    assert_eq!(fc["features"][0]["properties"]["id"], format!("fresh:{p}"));
    served.stop().await;
}

#[tokio::test]
async fn graceful_shutdown_releases_running_jobs_for_the_next_start() {
    let gate = GateRunner::new("g", true);
    let first = spawn_with(gate.clone(), None, None, |_| {}).await;
    let (p, t) = upload_pair(&first, "tile.las").await;
    let id = first.job_ok(json!({"points": [p], "trajectory": t})).await;
    first.wait_status(&id, "running").await;
    let (dir, clock) = (first.dir.clone(), first.clock.clone());
    first.stop().await;
    let job = open_queue(&dir, clock.clone())
        .await
        .get(&id)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(job.status, JobStatus::Queued, "released, not failed");
    assert_eq!(job.attempts, 0, "an interrupted attempt does not count");
    assert!(job.lease_owner.is_none());

    let second = spawn_with(EchoRunner::new("after"), Some(dir), Some(clock), |_| {}).await;
    let job = second.wait_finished(&id, Duration::from_secs(30)).await;
    assert_eq!(job["status"], "succeeded");
    assert_eq!(job["attempts"], 1);
    second.stop().await;
}

// =============================================================================================
// End to end: the real pipeline on a simulated survey, scored with the evaluator
// =============================================================================================

/// `roadmark simulate --scene NAME --out DIR` (the binary under test): an 80 m drive cut into
/// `tiles` LAS tiles; returns the tile paths.
fn simulate(scene: &str, out: &Path, tiles: usize) -> Vec<PathBuf> {
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_roadmark"))
        .args([
            "simulate",
            "--scene",
            scene,
            "--seed",
            "7",
            "--length-m",
            "80",
            "--tiles",
        ])
        .arg(tiles.to_string())
        .arg("--out")
        .arg(out)
        .status()
        .expect("running roadmark simulate");
    assert!(status.success(), "roadmark simulate --scene {scene} failed");
    if tiles == 1 {
        vec![out.join("points.las")]
    } else {
        (0..tiles)
            .map(|i| out.join(format!("points_{i:03}.las")))
            .collect()
    }
}

/// Score a fetched GeoJSON against the survey's truth.
fn score(fc: &Value, truth: &Path) -> roadmark::eval::Report {
    let result =
        roadmark::pipeline::geojson::from_geojson(fc).expect("the result parses in the contract schema");
    let truth = roadmark::pipeline::geojson::read_geojson(truth).unwrap();
    roadmark::eval::evaluate(&truth, &result, &roadmark::eval::EvalOptions::default()).unwrap()
}

/// Poll to `succeeded`, fetch the result in both CRS modes, compare with the pipeline run
/// directly on the same files, and score both answers with the evaluator.
async fn check_end_to_end(app: &TestApp, id: &str, tiles: &[PathBuf], survey: &Path) {
    let job = app.wait_finished(id, Duration::from_secs(900)).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(job["attempts"], 1);
    let (status, native) = app.result(id, Some("native")).await;
    assert_eq!(status, 200, "{native}");
    let (status, wgs84) = app.result(id, Some("wgs84")).await;
    assert_eq!(status, 200, "{wgs84}");
    let (_, default) = app.result(id, None).await;
    assert_eq!(default, wgs84, "wgs84 is the default when the CRS is known");
    assert_eq!(
        native["crs"]["properties"]["name"], "EPSG:32650",
        "{}",
        native["crs"]
    );
    assert!(wgs84.get("crs").is_none(), "RFC 7946 output has no crs member");

    // The service's answer is the pipeline's answer.
    let served = roadmark::pipeline::geojson::from_geojson(&native).unwrap();
    let inputs = Inputs {
        points: tiles.to_vec(),
        trajectory: survey.join("trajectory.csv"),
    };
    let params = roadmark::pipeline::params::Params::default().validate().unwrap();
    let expected = roadmark::pipeline::run(&inputs, &params, &roadmark::pipeline::NoProgress).unwrap();
    assert_eq!(served.markings.len(), expected.markings.len());
    assert_eq!(served.lane_lines.len(), expected.lane_lines.len());
    assert!(!served.markings.is_empty(), "no markings found");

    let truth = survey.join("truth.geojson");
    let (r_native, r_wgs84) = (score(&native, &truth), score(&wgs84, &truth));
    println!(
        "evaluation of the service's answer (crs=native):\n{}",
        r_native.to_text()
    );
    let f = |r: &roadmark::eval::Report| r.pixel.f_score.unwrap_or(0.0);
    // The pipeline scores ≈ 0.63 on this 80 m survey (the first metres of a drive have no
    // scan behind them); the service must deliver that, not just something.
    assert!(
        f(&r_native) >= 0.5,
        "the service's answer scores pixel F {} < 0.5",
        f(&r_native)
    );
    assert!(
        (f(&r_native) - f(&r_wgs84)).abs() < 0.02,
        "the CRS of the answer changes the score: {} vs {}",
        f(&r_native),
        f(&r_wgs84)
    );
}

#[tokio::test]
async fn end_to_end_simulated_survey_by_upload_ids() {
    let survey = tempfile::tempdir().unwrap();
    let tiles = simulate("highway", survey.path(), 1);
    let app = spawn_app().await;
    let p = app
        .upload_ok(std::fs::read(&tiles[0]).unwrap(), "points.las")
        .await;
    let traj = std::fs::read(survey.path().join("trajectory.csv")).unwrap();
    let t = app.upload_ok(traj, "trajectory.csv").await;
    let id = app.job_ok(json!({"points": [p], "trajectory": t})).await;
    check_end_to_end(&app, &id, &tiles, survey.path()).await;
    app.stop().await;
}

#[tokio::test]
async fn end_to_end_simulated_survey_by_multipart_with_two_tiles() {
    let survey = tempfile::tempdir().unwrap();
    let tiles = simulate("highway", survey.path(), 2);
    let app = spawn_app().await;
    let file = |path: &Path| {
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        reqwest::multipart::Part::bytes(std::fs::read(path).unwrap()).file_name(name)
    };
    let form = reqwest::multipart::Form::new()
        .part("points", file(&tiles[0]))
        .part("points", file(&tiles[1]))
        .part("trajectory", file(&survey.path().join("trajectory.csv")));
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let job: Value = r.json().await.unwrap();
    check_end_to_end(&app, job["id"].as_str().unwrap(), &tiles, survey.path()).await;
    app.stop().await;
}
