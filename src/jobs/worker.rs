//! Workers: claim → run → complete, with a heartbeat and throttled progress.
//!
//! **What.** Each worker is an async task looping over the queue. For a claimed job it loads the
//! inputs and resolved parameters, hands the CPU work to the rayon pool (one `pool.spawn`, its
//! answer back through a oneshot channel; the async runtime never blocks), and while the job
//! runs it supervises it from the async side:
//! - every `progress_ms` it writes the latest reported stage/fraction if it changed (so the
//!   pipeline can report as often as it likes: the database sees at most one write per period);
//! - every `heartbeat_ms` it extends the lease, learning on the way whether the user asked to
//!   cancel; a heartbeat that finds the lease gone marks the job lost;
//! - on shutdown it raises the job's stop flag.
//!
//! The pipeline sees all three signals (user cancel, shutdown, lost lease) through one
//! [`Progress::is_cancelled`] and stops at its next stage boundary. The worker then tells them
//! apart: a user cancel ends the job `cancelled`; a shutdown *releases* it back to the queue
//! (the interrupted attempt does not count); a lost lease writes nothing at all.
//!
//! **Outcomes.** Success: the Extraction is written durably to a file named after this claim,
//! then the job is marked succeeded by one fenced update naming that file; if the fence rejects
//! it (the lease was lost meanwhile) the file is deleted, so exactly one result survives.
//! Transient failure ([`PipelineError::is_retryable`]): back to the queue after an exponential
//! backoff, until `max_attempts`. Bad input, bad parameters, a panic: failed at once, with the
//! message naming the upload (never a server path).
//!
//! **Parameters.** [`WorkerSettings`] (from [`crate::config::Config`]).

use super::queue::{JobRecord, Queue, QueueError, backoff_ms};
use super::runner::Runner;
use crate::pipeline::params::{Params, ValidParams};
use crate::pipeline::{Extraction, Inputs, PipelineError, Progress};
use crate::storage::Storage;
use std::panic::AssertUnwindSafe;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;
use tokio::sync::{Notify, oneshot};
use tokio::time::{Instant, MissedTickBehavior};
use tokio_util::sync::CancellationToken;
use tracing::{Instrument, error, info, info_span, warn};

/// Timings and limits of the workers.
#[derive(Clone, Debug)]
pub struct WorkerSettings {
    pub lease_ms: u64,
    pub heartbeat_ms: u64,
    pub progress_ms: u64,
    pub poll_ms: u64,
    pub retry_base_ms: u64,
    pub retry_max_ms: u64,
}

impl WorkerSettings {
    pub fn from_config(c: &crate::config::Config) -> WorkerSettings {
        WorkerSettings {
            lease_ms: c.lease_ms,
            heartbeat_ms: c.heartbeat_ms,
            progress_ms: c.progress_ms,
            poll_ms: c.poll_ms,
            retry_base_ms: c.retry_base_ms,
            retry_max_ms: c.retry_max_ms,
        }
    }
}

/// Everything a worker needs, shared by all workers of a process.
pub struct WorkerContext {
    pub queue: Queue,
    pub storage: Storage,
    pub runner: Arc<dyn Runner>,
    pub pool: Arc<rayon::ThreadPool>,
    pub settings: WorkerSettings,
    /// Signalled when a job is enqueued, so an idle worker starts at once instead of polling.
    pub wake: Arc<Notify>,
}

/// How one claimed job ended, as far as this worker is concerned.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JobOutcome {
    Succeeded,
    Failed {
        code: String,
    },
    /// Transient failure, back in the queue.
    Retrying,
    Cancelled,
    /// Shutdown: back in the queue, attempt not counted.
    Released,
    /// The lease was taken over; nothing was written.
    LeaseLost,
}

/// Run one worker until `shutdown` is cancelled (the job in hand reaches a safe point first).
pub async fn run_worker(ctx: Arc<WorkerContext>, name: String, shutdown: CancellationToken) {
    info!(worker = %name, "worker started");
    let poll = Duration::from_millis(ctx.settings.poll_ms);
    while !shutdown.is_cancelled() {
        match run_once(&ctx, &name, &shutdown).await {
            Ok(Some(_)) => continue,
            Ok(None) => {}
            Err(e) => error!(worker = %name, error = %e, "claiming a job failed"),
        }
        tokio::select! {
            () = ctx.wake.notified() => {}
            () = tokio::time::sleep(poll) => {}
            () = shutdown.cancelled() => break,
        }
    }
    info!(worker = %name, "worker stopped");
}

/// Claim one due job (if any) and process it to an outcome. Tests drive the queue with this
/// until it returns `None`, without sleeping.
pub async fn run_once(
    ctx: &WorkerContext,
    name: &str,
    shutdown: &CancellationToken,
) -> sqlx::Result<Option<(String, JobOutcome)>> {
    ctx.queue.sweep().await?;
    let token = uuid::Uuid::new_v4().simple().to_string();
    let owner = format!("{name}/{token}");
    let Some(job) = ctx.queue.claim(&owner, ctx.settings.lease_ms).await? else {
        return Ok(None);
    };
    let span = info_span!("job", job_id = %job.id, attempt = job.attempts, worker = %name);
    let id = job.id.clone();
    let outcome = process(ctx, job, &owner, &token, shutdown).instrument(span).await;
    Ok(Some((id, outcome)))
}

/// The pipeline's view of its job: progress sink and stop flags.
#[derive(Default)]
struct JobControl {
    user_cancel: AtomicBool,
    shutdown: AtomicBool,
    lease_lost: AtomicBool,
    latest: Mutex<Option<(String, f64)>>,
    /// Bumped by every report, so the supervisor writes only when something changed.
    version: AtomicU64,
}

impl Progress for JobControl {
    fn report(&self, stage: &str, fraction: f64) {
        let mut latest = self.latest.lock().unwrap_or_else(|e| e.into_inner());
        *latest = Some((stage.to_string(), fraction));
        self.version.fetch_add(1, Ordering::Release);
    }

    fn is_cancelled(&self) -> bool {
        self.user_cancel.load(Ordering::Acquire)
            || self.shutdown.load(Ordering::Acquire)
            || self.lease_lost.load(Ordering::Acquire)
    }
}

impl JobControl {
    fn latest(&self) -> Option<(String, f64)> {
        self.latest.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

/// Inputs and parameters of a job, plus labels to name its files in messages.
struct Prepared {
    inputs: Inputs,
    params: ValidParams,
    labels: Vec<(PathBuf, String)>,
}

type RunResult = std::thread::Result<Result<Extraction, PipelineError>>;

async fn process(
    ctx: &WorkerContext,
    job: JobRecord,
    owner: &str,
    token: &str,
    shutdown: &CancellationToken,
) -> JobOutcome {
    info!("job claimed");
    let prepared = match prepare(ctx, &job).await {
        Ok(p) => p,
        Err(Prep::Fatal(code, message)) => return finish_failed(ctx, &job, owner, code, &message).await,
        Err(Prep::Transient(message)) => return retry_or_fail(ctx, &job, owner, "io-error", &message).await,
    };

    let control = Arc::new(JobControl::default());
    let (tx, mut rx) = oneshot::channel::<RunResult>();
    {
        let runner = ctx.runner.clone();
        let control = control.clone();
        let Prepared { inputs, params, .. } = &prepared;
        let (inputs, params) = (inputs.clone(), params.clone());
        // CPU work leaves the async runtime here. A panic must not abort the process (rayon
        // aborts on panics in `spawn`), so it is caught and becomes a failed job.
        ctx.pool.spawn(move || {
            let result =
                std::panic::catch_unwind(AssertUnwindSafe(|| runner.run(&inputs, &params, &*control)));
            let _ = tx.send(result);
        });
    }

    let mut tick = tokio::time::interval(Duration::from_millis(ctx.settings.progress_ms));
    tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
    let heartbeat_every = Duration::from_millis(ctx.settings.heartbeat_ms);
    let mut last_heartbeat = Instant::now();
    let mut written_version = 0;
    let result = loop {
        tokio::select! {
            result = &mut rx => break result,
            () = shutdown.cancelled(), if !control.shutdown.load(Ordering::Acquire) => {
                info!("shutdown: asking the job to stop at its next stage boundary");
                control.shutdown.store(true, Ordering::Release);
            }
            _ = tick.tick() => {
                if control.lease_lost.load(Ordering::Acquire) {
                    continue;
                }
                let version = control.version.load(Ordering::Acquire);
                if version != written_version
                    && let Some((stage, fraction)) = control.latest()
                {
                    written_version = version;
                    let r = ctx.queue.set_progress(&job.id, owner, &stage, fraction).await;
                    observe_lease(&control, r);
                }
                if last_heartbeat.elapsed() >= heartbeat_every {
                    last_heartbeat = Instant::now();
                    let r = ctx.queue.heartbeat(&job.id, owner, ctx.settings.lease_ms).await;
                    observe_lease(&control, r);
                }
            }
        }
    };

    if control.lease_lost.load(Ordering::Acquire) {
        warn!("lease lost while running; another worker owns the job now, nothing written");
        return JobOutcome::LeaseLost;
    }
    // A dropped sender (the pool task vanished without answering) is treated like a panic.
    let result: RunResult =
        result.unwrap_or_else(|_| Err(Box::new("the pipeline task ended without an answer")));
    match result {
        Ok(Ok(extraction)) => store_result(ctx, &job, owner, token, extraction).await,
        Ok(Err(PipelineError::Cancelled)) => {
            if control.user_cancel.load(Ordering::Acquire) || !control.shutdown.load(Ordering::Acquire) {
                match ctx.queue.mark_cancelled(&job.id, owner).await {
                    Ok(()) => {
                        info!("job cancelled");
                        JobOutcome::Cancelled
                    }
                    Err(e) => written_or_lost(e),
                }
            } else {
                match ctx.queue.release(&job.id, owner).await {
                    Ok(()) => {
                        info!("job released back to the queue for the next start");
                        JobOutcome::Released
                    }
                    Err(e) => written_or_lost(e),
                }
            }
        }
        Ok(Err(e)) => {
            let message = describe(&e, &prepared.labels);
            if e.is_retryable() {
                retry_or_fail(ctx, &job, owner, error_code(&e), &message).await
            } else {
                finish_failed(ctx, &job, owner, error_code(&e), &message).await
            }
        }
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            error!(panic = %what, "the pipeline panicked");
            finish_failed(
                ctx,
                &job,
                owner,
                "internal-error",
                &format!("internal error: {what}"),
            )
            .await
        }
    }
}

fn observe_lease(control: &JobControl, r: Result<super::queue::LeaseState, QueueError>) {
    match r {
        Ok(state) => {
            if state.cancel_requested && !control.user_cancel.swap(true, Ordering::AcqRel) {
                info!("cancellation requested: stopping at the next stage boundary");
            }
        }
        Err(QueueError::LeaseLost { .. }) => control.lease_lost.store(true, Ordering::Release),
        // A failed write is not a lost lease: the next heartbeat tries again well before expiry.
        Err(QueueError::Db(e)) => warn!(error = %e, "progress/heartbeat write failed"),
    }
}

enum Prep {
    Fatal(&'static str, String),
    Transient(String),
}

async fn prepare(ctx: &WorkerContext, job: &JobRecord) -> Result<Prepared, Prep> {
    let params: Params = serde_json::from_str(&job.params)
        .map_err(|e| Prep::Fatal("invalid-params", format!("stored parameters unreadable: {e}")))?;
    let params = params.validate().map_err(|e| Prep::Fatal("invalid-params", e))?;
    let rows = ctx
        .queue
        .inputs(&job.id)
        .await
        .map_err(|e| Prep::Transient(format!("reading the job's inputs: {e}")))?;
    let mut points = Vec::new();
    let mut trajectory = None;
    let mut labels = Vec::new();
    for row in rows {
        let path = ctx.storage.resolve(&row.path);
        let label = match &row.filename {
            Some(name) => format!("upload {} ({name})", row.upload_id),
            None => format!("upload {}", row.upload_id),
        };
        labels.push((path.clone(), label));
        if row.role == "trajectory" {
            trajectory = Some(path);
        } else {
            points.push(path);
        }
    }
    let trajectory =
        trajectory.ok_or_else(|| Prep::Fatal("internal-error", "job has no trajectory".into()))?;
    if points.is_empty() {
        return Err(Prep::Fatal("internal-error", "job has no point tiles".into()));
    }
    Ok(Prepared {
        inputs: Inputs { points, trajectory },
        params,
        labels,
    })
}

async fn store_result(
    ctx: &WorkerContext,
    job: &JobRecord,
    owner: &str,
    token: &str,
    extraction: Extraction,
) -> JobOutcome {
    let rel = Storage::result_rel(&job.id, token);
    let storage = ctx.storage.clone();
    let rel_w = rel.clone();
    let written = tokio::task::spawn_blocking(move || -> std::io::Result<()> {
        let bytes = serde_json::to_vec(&extraction).map_err(std::io::Error::other)?;
        storage.write_durably(&rel_w, &bytes).map(|_| ())
    })
    .await
    .unwrap_or_else(|e| Err(std::io::Error::other(e)));
    if let Err(e) = written {
        let message = format!("writing the result: {e}");
        return retry_or_fail(ctx, job, owner, "io-error", &message).await;
    }
    match ctx.queue.complete(&job.id, owner, &rel).await {
        Ok(()) => {
            info!(result = %rel, "job succeeded");
            JobOutcome::Succeeded
        }
        Err(e) => {
            // Not ours any more (or the database failed): the file must not survive, since the
            // row does not point to it. Whoever holds the lease now writes its own.
            if let Err(io) = ctx.storage.remove(&rel) {
                warn!(error = %io, "removing an orphan result failed");
            }
            written_or_lost(e)
        }
    }
}

async fn retry_or_fail(
    ctx: &WorkerContext,
    job: &JobRecord,
    owner: &str,
    code: &str,
    message: &str,
) -> JobOutcome {
    if job.attempts >= job.max_attempts {
        let message = format!("{message} (gave up after {} attempts)", job.attempts);
        return finish_failed(ctx, job, owner, code, &message).await;
    }
    let delay = backoff_ms(
        job.attempts,
        ctx.settings.retry_base_ms,
        ctx.settings.retry_max_ms,
    );
    match ctx.queue.retry_later(&job.id, owner, code, message, delay).await {
        Ok(()) => {
            warn!(error = %message, delay_ms = delay, "transient failure, retrying later");
            JobOutcome::Retrying
        }
        Err(e) => written_or_lost(e),
    }
}

async fn finish_failed(
    ctx: &WorkerContext,
    job: &JobRecord,
    owner: &str,
    code: &str,
    message: &str,
) -> JobOutcome {
    match ctx.queue.fail(&job.id, owner, code, message).await {
        Ok(()) => {
            warn!(code, error = %message, "job failed");
            JobOutcome::Failed {
                code: code.to_string(),
            }
        }
        Err(e) => written_or_lost(e),
    }
}

fn written_or_lost(e: QueueError) -> JobOutcome {
    match e {
        QueueError::LeaseLost { .. } => {
            warn!("lease lost before the outcome was written; the new owner decides");
        }
        // The lease expires and another attempt runs: nothing is lost.
        QueueError::Db(e) => error!(error = %e, "writing the job outcome failed"),
    }
    JobOutcome::LeaseLost
}

/// Stable error codes stored with failed jobs.
fn error_code(e: &PipelineError) -> &'static str {
    match e {
        PipelineError::Input { .. } => "invalid-input",
        PipelineError::Params(_) => "invalid-params",
        PipelineError::Io { .. } => "io-error",
        PipelineError::Cancelled => "cancelled",
        PipelineError::Model(_) => "model-error",
        PipelineError::Internal(_) => "internal-error",
    }
}

/// The error message with server paths replaced by the uploads they hold.
fn describe(e: &PipelineError, labels: &[(PathBuf, String)]) -> String {
    let label_of = |path: &std::path::Path| {
        labels
            .iter()
            .find(|(p, _)| p == path)
            .map_or_else(|| "input file".to_string(), |(_, l)| l.clone())
    };
    match e {
        PipelineError::Input { path, message } => format!("{}: {message}", label_of(path)),
        PipelineError::Io { path, source } => format!("{}: {source}", label_of(path)),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_uploads_not_server_paths() {
        let labels = vec![(
            PathBuf::from("/data/uploads/a.las"),
            "upload a (tile.las)".to_string(),
        )];
        let e = PipelineError::input("/data/uploads/a.las", "no intensity");
        assert_eq!(describe(&e, &labels), "upload a (tile.las): no intensity");
        let e = PipelineError::input("/elsewhere", "bad");
        assert_eq!(describe(&e, &labels), "input file: bad");
    }

    #[test]
    fn control_reports_and_stops() {
        let c = JobControl::default();
        assert!(!c.is_cancelled());
        c.report("rasterize", 0.5);
        assert_eq!(c.latest(), Some(("rasterize".into(), 0.5)));
        c.shutdown.store(true, Ordering::Release);
        assert!(c.is_cancelled());
    }
}
