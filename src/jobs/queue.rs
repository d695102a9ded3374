//! All SQL of the service: uploads and the job queue, on SQLite through sqlx.
//!
//! **What.** A durable queue with leases, in the style of effectum and apalis-sqlite: one row
//! per job; workers claim, heartbeat and finish jobs through the methods here; the HTTP layer
//! enqueues, reads, lists and cancels.
//!
//! **Algorithm.**
//! - *Claim* is ONE statement, `UPDATE jobs SET status='running', lease_owner=?, … WHERE seq =
//!   (SELECT seq … LIMIT 1) RETURNING …`. SQLite runs a write statement under its single writer
//!   lock, so two workers (or two processes on the same file) can never claim the same row. The
//!   candidates are queued jobs whose `run_after` has passed and running jobs whose lease expired
//!   (their worker died); attempts are counted here, at claim.
//! - *Lease*: `lease_owner` (a token unique to one claim) + `lease_expires_at`; the worker's
//!   heartbeat extends it. Every write a worker makes under its lease — progress, heartbeat,
//!   success, failure, retry, release — carries `WHERE id = ? AND lease_owner = ? AND status =
//!   'running'`, so a worker whose lease expired and was re-claimed cannot overwrite anything;
//!   it gets [`QueueError::LeaseLost`].
//! - *Retries*: transient failures go back to `queued` with `run_after = now + delay`; the
//!   caller computes the exponential backoff ([`backoff_ms`]). [`Queue::sweep`] ends jobs whose
//!   lease expired after their last attempt (a job that crashes its process every time) and
//!   expired jobs whose cancellation was requested, instead of running them again.
//! - *Cancel*: queued jobs become `cancelled` at once; running jobs get `cancel_requested`,
//!   which the worker reads with its heartbeat and turns into a stop at the next stage boundary.
//!
//! **Parameters.** Lease length, attempts and delays come from [`crate::config::Config`]; the
//! clock is injected ([`Clock`]) so tests expire leases without sleeping.
//!
//! **Complexity.** Claim and sweep use the `(status, run_after, seq)` and
//! `(status, lease_expires_at)` indexes; listing is keyset pagination on `seq`, O(limit).

use super::clock::Clock;
use serde::{Deserialize, Serialize};
use sqlx::sqlite::{
    SqliteConnectOptions, SqliteJournalMode, SqlitePool, SqlitePoolOptions, SqliteSynchronous,
};
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

/// Where a job is in its life.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, sqlx::Type, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
#[sqlx(type_name = "TEXT", rename_all = "lowercase")]
pub enum JobStatus {
    Queued,
    Running,
    Succeeded,
    Failed,
    Cancelled,
}

impl JobStatus {
    pub fn as_str(self) -> &'static str {
        match self {
            JobStatus::Queued => "queued",
            JobStatus::Running => "running",
            JobStatus::Succeeded => "succeeded",
            JobStatus::Failed => "failed",
            JobStatus::Cancelled => "cancelled",
        }
    }

    /// Succeeded, failed and cancelled jobs never change again.
    pub fn is_terminal(self) -> bool {
        matches!(
            self,
            JobStatus::Succeeded | JobStatus::Failed | JobStatus::Cancelled
        )
    }
}

/// One row of `jobs`.
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct JobRecord {
    pub seq: i64,
    pub id: String,
    pub status: JobStatus,
    /// Resolved parameters (JSON of `ValidParams`).
    pub params: String,
    pub created_at: i64,
    pub updated_at: i64,
    pub started_at: Option<i64>,
    pub finished_at: Option<i64>,
    pub run_after: i64,
    pub attempts: i64,
    pub max_attempts: i64,
    pub lease_owner: Option<String>,
    pub lease_expires_at: Option<i64>,
    pub cancel_requested: bool,
    pub progress_stage: Option<String>,
    pub progress_fraction: Option<f64>,
    pub error_code: Option<String>,
    pub error_message: Option<String>,
    pub result_path: Option<String>,
}

/// The columns of [`JobRecord`], for `SELECT` and `RETURNING` (a macro so SQL stays `'static`).
macro_rules! job_columns {
    () => {
        "seq, id, status, params, created_at, updated_at, started_at, finished_at, run_after, \
         attempts, max_attempts, lease_owner, lease_expires_at, cancel_requested, progress_stage, \
         progress_fraction, error_code, error_message, result_path"
    };
}

/// One row of `uploads`.
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct UploadRecord {
    pub id: String,
    /// `las`, `laz` or `trajectory`.
    pub kind: String,
    pub filename: Option<String>,
    pub size: i64,
    pub sha256: String,
    /// Relative to the data directory.
    pub path: String,
    /// JSON summary (point count, bounds, CRS; or trajectory rows).
    pub summary: String,
    pub created_at: i64,
}

/// One input file of a job, joined with its upload.
#[derive(Clone, Debug, sqlx::FromRow)]
pub struct JobInput {
    /// `points` or `trajectory`.
    pub role: String,
    pub position: i64,
    pub upload_id: String,
    pub kind: String,
    pub filename: Option<String>,
    pub path: String,
}

/// A job to enqueue: validated inputs and resolved parameters.
#[derive(Clone, Debug)]
pub struct NewJob {
    pub points: Vec<String>,
    pub trajectory: String,
    pub params: String,
    pub max_attempts: u32,
}

#[derive(Debug, thiserror::Error)]
pub enum QueueError {
    /// The lease was taken over (expired and re-claimed) or the job already ended.
    #[error("job {job}: the lease is no longer held by this worker")]
    LeaseLost { job: String },
    #[error(transparent)]
    Db(#[from] sqlx::Error),
}

/// What a heartbeat learns about its job.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LeaseState {
    pub cancel_requested: bool,
}

/// The outcome of `DELETE /v1/jobs/{id}`.
#[derive(Clone, Debug)]
pub enum CancelOutcome {
    /// The job was queued and is now cancelled.
    Cancelled(JobRecord),
    /// The job is running; it stops at its next stage boundary.
    Requested(JobRecord),
    /// The job had already ended (any terminal status, including cancelled).
    AlreadyFinished(JobRecord),
    NotFound,
}

/// Exponential backoff before attempt `attempts + 1`: `base · 2^(attempts-1)`, capped.
pub fn backoff_ms(attempts: i64, base_ms: u64, max_ms: u64) -> i64 {
    let exp = u32::try_from((attempts - 1).clamp(0, 30)).unwrap_or(30);
    let delay = base_ms.saturating_mul(1u64 << exp).min(max_ms);
    i64::try_from(delay).unwrap_or(i64::MAX)
}

/// Handle to the database (cheap to clone: a pool and a clock).
#[derive(Clone)]
pub struct Queue {
    pool: SqlitePool,
    clock: Arc<dyn Clock>,
}

impl Queue {
    /// Open (creating if needed) the database file, switch to WAL, run the migrations.
    pub async fn connect(path: &Path, clock: Arc<dyn Clock>) -> anyhow::Result<Queue> {
        let options = SqliteConnectOptions::new()
            .filename(path)
            .create_if_missing(true)
            // WAL: readers (status polls) never wait for the writer (workers).
            .journal_mode(SqliteJournalMode::Wal)
            // FULL: a job marked succeeded stays succeeded after a power cut.
            .synchronous(SqliteSynchronous::Full)
            .busy_timeout(Duration::from_secs(10))
            .foreign_keys(true);
        let pool = SqlitePoolOptions::new()
            .max_connections(8)
            .connect_with(options)
            .await?;
        sqlx::migrate!("./migrations").run(&pool).await?;
        Ok(Queue { pool, clock })
    }

    pub fn now_ms(&self) -> i64 {
        self.clock.now_ms()
    }

    /// Cheap liveness check of the database.
    pub async fn ping(&self) -> sqlx::Result<()> {
        sqlx::query("SELECT 1").execute(&self.pool).await.map(|_| ())
    }

    pub async fn close(&self) {
        self.pool.close().await;
    }

    // ---- uploads -------------------------------------------------------------------------

    pub async fn insert_upload(&self, u: &UploadRecord) -> sqlx::Result<()> {
        sqlx::query(
            "INSERT INTO uploads (id, kind, filename, size, sha256, path, summary, created_at)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
        )
        .bind(&u.id)
        .bind(&u.kind)
        .bind(&u.filename)
        .bind(u.size)
        .bind(&u.sha256)
        .bind(&u.path)
        .bind(&u.summary)
        .bind(u.created_at)
        .execute(&self.pool)
        .await
        .map(|_| ())
    }

    pub async fn get_upload(&self, id: &str) -> sqlx::Result<Option<UploadRecord>> {
        sqlx::query_as(
            "SELECT id, kind, filename, size, sha256, path, summary, created_at FROM uploads WHERE id = ?1",
        )
        .bind(id)
        .fetch_optional(&self.pool)
        .await
    }

    /// Delete an upload no job refers to (cleanup after a failed multipart job request).
    pub async fn delete_unused_upload(&self, id: &str) -> sqlx::Result<bool> {
        let done = sqlx::query(
            "DELETE FROM uploads WHERE id = ?1
               AND NOT EXISTS (SELECT 1 FROM job_inputs WHERE upload_id = ?1)",
        )
        .bind(id)
        .execute(&self.pool)
        .await?;
        Ok(done.rows_affected() == 1)
    }

    // ---- jobs: the HTTP side -------------------------------------------------------------

    /// Insert a queued job and its inputs in one transaction.
    pub async fn enqueue(&self, job: &NewJob) -> sqlx::Result<JobRecord> {
        let id = uuid::Uuid::new_v4().to_string();
        let now = self.now_ms();
        let mut tx = self.pool.begin().await?;
        let record: JobRecord = sqlx::query_as(concat!(
            "INSERT INTO jobs (id, status, params, created_at, updated_at, run_after, max_attempts,
                               progress_stage, progress_fraction)
             VALUES (?1, 'queued', ?2, ?3, ?3, ?3, ?4, 'queued', 0.0)
             RETURNING ",
            job_columns!()
        ))
        .bind(&id)
        .bind(&job.params)
        .bind(now)
        .bind(i64::from(job.max_attempts))
        .fetch_one(&mut *tx)
        .await?;
        let inputs = job
            .points
            .iter()
            .enumerate()
            .map(|(i, u)| ("points", i, u))
            .chain(std::iter::once(("trajectory", 0, &job.trajectory)));
        for (role, position, upload) in inputs {
            sqlx::query("INSERT INTO job_inputs (job_id, role, position, upload_id) VALUES (?1, ?2, ?3, ?4)")
                .bind(&id)
                .bind(role)
                .bind(i64::try_from(position).unwrap_or(i64::MAX))
                .bind(upload)
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        Ok(record)
    }

    pub async fn get(&self, id: &str) -> sqlx::Result<Option<JobRecord>> {
        sqlx::query_as(concat!("SELECT ", job_columns!(), " FROM jobs WHERE id = ?1"))
            .bind(id)
            .fetch_optional(&self.pool)
            .await
    }

    /// The input files of a job: points tiles in the order given, then the trajectory.
    pub async fn inputs(&self, job_id: &str) -> sqlx::Result<Vec<JobInput>> {
        sqlx::query_as(
            "SELECT i.role, i.position, i.upload_id, u.kind, u.filename, u.path
               FROM job_inputs i JOIN uploads u ON u.id = i.upload_id
              WHERE i.job_id = ?1
              ORDER BY i.role = 'trajectory', i.position",
        )
        .bind(job_id)
        .fetch_all(&self.pool)
        .await
    }

    /// Newest first; `before_seq` is the keyset cursor (the `seq` of the last job already seen).
    pub async fn list(
        &self,
        status: Option<JobStatus>,
        before_seq: Option<i64>,
        limit: u32,
    ) -> sqlx::Result<Vec<JobRecord>> {
        sqlx::query_as(concat!(
            "SELECT ",
            job_columns!(),
            " FROM jobs WHERE (?1 IS NULL OR status = ?1) AND (?2 IS NULL OR seq < ?2)
              ORDER BY seq DESC LIMIT ?3"
        ))
        .bind(status)
        .bind(before_seq)
        .bind(i64::from(limit))
        .fetch_all(&self.pool)
        .await
    }

    /// Number of jobs per status.
    pub async fn counts(&self) -> sqlx::Result<Vec<(JobStatus, i64)>> {
        sqlx::query_as("SELECT status, COUNT(*) FROM jobs GROUP BY status ORDER BY status")
            .fetch_all(&self.pool)
            .await
    }

    /// Cancel: a queued job ends at once; a running one is asked to stop.
    pub async fn cancel(&self, id: &str) -> sqlx::Result<CancelOutcome> {
        let now = self.now_ms();
        // SET expressions see the row as it was before the update, so `status` below is the
        // old status: one statement decides and writes atomically.
        let updated: Option<JobRecord> = sqlx::query_as(concat!(
            "UPDATE jobs
                SET status = CASE WHEN status = 'queued' THEN 'cancelled' ELSE status END,
                    finished_at = CASE WHEN status = 'queued' THEN ?2 ELSE finished_at END,
                    progress_stage = CASE WHEN status = 'queued' THEN 'cancelled' ELSE progress_stage END,
                    cancel_requested = 1,
                    updated_at = ?2
              WHERE id = ?1 AND status IN ('queued', 'running')
              RETURNING ",
            job_columns!()
        ))
        .bind(id)
        .bind(now)
        .fetch_optional(&self.pool)
        .await?;
        Ok(match updated {
            Some(job) if job.status == JobStatus::Cancelled => CancelOutcome::Cancelled(job),
            Some(job) => CancelOutcome::Requested(job),
            None => match self.get(id).await? {
                Some(job) => CancelOutcome::AlreadyFinished(job),
                None => CancelOutcome::NotFound,
            },
        })
    }

    // ---- jobs: the worker side -----------------------------------------------------------

    /// End jobs whose lease expired and which must not run again: out of attempts (their worker
    /// died every time) or cancelled meanwhile. Returns how many rows changed.
    pub async fn sweep(&self) -> sqlx::Result<u64> {
        let now = self.now_ms();
        let done = sqlx::query(
            "UPDATE jobs
                SET status = CASE WHEN cancel_requested = 1 THEN 'cancelled' ELSE 'failed' END,
                    error_code = CASE WHEN cancel_requested = 1 THEN NULL ELSE 'worker-lost' END,
                    error_message = CASE WHEN cancel_requested = 1 THEN NULL
                        ELSE 'the worker running this job stopped responding on its last attempt ('
                             || attempts || ' of ' || max_attempts || ')' END,
                    lease_owner = NULL, lease_expires_at = NULL, finished_at = ?1, updated_at = ?1
              WHERE status = 'running' AND lease_expires_at <= ?1
                AND (attempts >= max_attempts OR cancel_requested = 1)",
        )
        .bind(now)
        .execute(&self.pool)
        .await?;
        Ok(done.rows_affected())
    }

    /// Claim the oldest due job for `owner` (a token unique to this claim), leasing it for
    /// `lease_ms`. One atomic statement; also takes over running jobs whose lease expired.
    pub async fn claim(&self, owner: &str, lease_ms: u64) -> sqlx::Result<Option<JobRecord>> {
        let now = self.now_ms();
        sqlx::query_as(concat!(
            "UPDATE jobs
                SET status = 'running', lease_owner = ?1, lease_expires_at = ?2 + ?3,
                    attempts = attempts + 1, started_at = COALESCE(started_at, ?2), updated_at = ?2,
                    progress_stage = 'starting', progress_fraction = 0.0
              WHERE seq = (
                    SELECT seq FROM jobs
                     WHERE (status = 'queued' AND run_after <= ?2)
                        OR (status = 'running' AND lease_expires_at <= ?2
                            AND attempts < max_attempts AND cancel_requested = 0)
                     ORDER BY seq
                     LIMIT 1)
              RETURNING ",
            job_columns!()
        ))
        .bind(owner)
        .bind(now)
        .bind(i64::try_from(lease_ms).unwrap_or(i64::MAX))
        .fetch_optional(&self.pool)
        .await
    }

    /// Extend the lease; tells whether cancellation was requested meanwhile.
    pub async fn heartbeat(&self, id: &str, owner: &str, lease_ms: u64) -> Result<LeaseState, QueueError> {
        let now = self.now_ms();
        let row: Option<(bool,)> = sqlx::query_as(
            "UPDATE jobs SET lease_expires_at = ?3 + ?4
              WHERE id = ?1 AND lease_owner = ?2 AND status = 'running'
              RETURNING cancel_requested",
        )
        .bind(id)
        .bind(owner)
        .bind(now)
        .bind(i64::try_from(lease_ms).unwrap_or(i64::MAX))
        .fetch_optional(&self.pool)
        .await?;
        row.map(|(cancel_requested,)| LeaseState { cancel_requested })
            .ok_or_else(|| lost(id))
    }

    /// Record progress (fenced); tells whether cancellation was requested meanwhile.
    pub async fn set_progress(
        &self,
        id: &str,
        owner: &str,
        stage: &str,
        fraction: f64,
    ) -> Result<LeaseState, QueueError> {
        let now = self.now_ms();
        let row: Option<(bool,)> = sqlx::query_as(
            "UPDATE jobs SET progress_stage = ?3, progress_fraction = ?4, updated_at = ?5
              WHERE id = ?1 AND lease_owner = ?2 AND status = 'running'
              RETURNING cancel_requested",
        )
        .bind(id)
        .bind(owner)
        .bind(stage)
        .bind(fraction.clamp(0.0, 1.0))
        .bind(now)
        .fetch_optional(&self.pool)
        .await?;
        row.map(|(cancel_requested,)| LeaseState { cancel_requested })
            .ok_or_else(|| lost(id))
    }

    /// Mark the job succeeded with its (already durably written) result file.
    pub async fn complete(&self, id: &str, owner: &str, result_rel: &str) -> Result<(), QueueError> {
        let now = self.now_ms();
        let done = sqlx::query(
            "UPDATE jobs
                SET status = 'succeeded', result_path = ?3, finished_at = ?4, updated_at = ?4,
                    lease_owner = NULL, lease_expires_at = NULL, progress_stage = 'done',
                    progress_fraction = 1.0, error_code = NULL, error_message = NULL
              WHERE id = ?1 AND lease_owner = ?2 AND status = 'running'",
        )
        .bind(id)
        .bind(owner)
        .bind(result_rel)
        .bind(now)
        .execute(&self.pool)
        .await?;
        fenced(done.rows_affected(), id)
    }

    /// Fail the job for good.
    pub async fn fail(&self, id: &str, owner: &str, code: &str, message: &str) -> Result<(), QueueError> {
        let now = self.now_ms();
        let done = sqlx::query(
            "UPDATE jobs
                SET status = 'failed', error_code = ?3, error_message = ?4, finished_at = ?5,
                    updated_at = ?5, lease_owner = NULL, lease_expires_at = NULL
              WHERE id = ?1 AND lease_owner = ?2 AND status = 'running'",
        )
        .bind(id)
        .bind(owner)
        .bind(code)
        .bind(message)
        .bind(now)
        .execute(&self.pool)
        .await?;
        fenced(done.rows_affected(), id)
    }

    /// Put the job back in the queue after a transient failure, due again in `delay_ms`.
    pub async fn retry_later(
        &self,
        id: &str,
        owner: &str,
        code: &str,
        message: &str,
        delay_ms: i64,
    ) -> Result<(), QueueError> {
        let now = self.now_ms();
        let done = sqlx::query(
            "UPDATE jobs
                SET status = 'queued', run_after = ?5 + ?6, error_code = ?3, error_message = ?4,
                    updated_at = ?5, lease_owner = NULL, lease_expires_at = NULL,
                    progress_stage = 'retry-wait'
              WHERE id = ?1 AND lease_owner = ?2 AND status = 'running'",
        )
        .bind(id)
        .bind(owner)
        .bind(code)
        .bind(message)
        .bind(now)
        .bind(delay_ms)
        .execute(&self.pool)
        .await?;
        fenced(done.rows_affected(), id)
    }

    /// Give the job back untouched (graceful shutdown): queued, due now, and the interrupted
    /// attempt does not count.
    pub async fn release(&self, id: &str, owner: &str) -> Result<(), QueueError> {
        let now = self.now_ms();
        let done = sqlx::query(
            "UPDATE jobs
                SET status = 'queued', attempts = MAX(attempts - 1, 0), run_after = ?3,
                    updated_at = ?3, lease_owner = NULL, lease_expires_at = NULL,
                    progress_stage = 'queued', progress_fraction = 0.0
              WHERE id = ?1 AND lease_owner = ?2 AND status = 'running'",
        )
        .bind(id)
        .bind(owner)
        .bind(now)
        .execute(&self.pool)
        .await?;
        fenced(done.rows_affected(), id)
    }

    /// The worker stopped the job on a cancellation request.
    pub async fn mark_cancelled(&self, id: &str, owner: &str) -> Result<(), QueueError> {
        let now = self.now_ms();
        let done = sqlx::query(
            "UPDATE jobs
                SET status = 'cancelled', finished_at = ?3, updated_at = ?3,
                    lease_owner = NULL, lease_expires_at = NULL, progress_stage = 'cancelled'
              WHERE id = ?1 AND lease_owner = ?2 AND status = 'running'",
        )
        .bind(id)
        .bind(owner)
        .bind(now)
        .execute(&self.pool)
        .await?;
        fenced(done.rows_affected(), id)
    }
}

fn lost(id: &str) -> QueueError {
    QueueError::LeaseLost { job: id.to_string() }
}

fn fenced(rows: u64, id: &str) -> Result<(), QueueError> {
    if rows == 1 { Ok(()) } else { Err(lost(id)) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::jobs::clock::ManualClock;

    async fn setup() -> (tempfile::TempDir, Queue, Arc<ManualClock>) {
        let dir = tempfile::tempdir().unwrap();
        let clock = Arc::new(ManualClock::new());
        let q = Queue::connect(&dir.path().join("q.db"), clock.clone())
            .await
            .unwrap();
        for id in ["p1", "t1"] {
            q.insert_upload(&UploadRecord {
                id: id.into(),
                kind: if id == "p1" { "las" } else { "trajectory" }.into(),
                filename: None,
                size: 1,
                sha256: "00".into(),
                path: format!("uploads/{id}"),
                summary: "{}".into(),
                created_at: 0,
            })
            .await
            .unwrap();
        }
        (dir, q, clock)
    }

    fn new_job() -> NewJob {
        NewJob {
            points: vec!["p1".into()],
            trajectory: "t1".into(),
            params: "{}".into(),
            max_attempts: 2,
        }
    }

    #[tokio::test]
    async fn claim_is_exclusive_and_counts_attempts() {
        let (_d, q, _c) = setup().await;
        let a = q.enqueue(&new_job()).await.unwrap();
        let b = q.enqueue(&new_job()).await.unwrap();
        let first = q.claim("w1", 1000).await.unwrap().unwrap();
        assert_eq!(first.id, a.id, "oldest first");
        assert_eq!(first.attempts, 1);
        assert_eq!(first.status, JobStatus::Running);
        let second = q.claim("w2", 1000).await.unwrap().unwrap();
        assert_eq!(second.id, b.id);
        assert!(q.claim("w3", 1000).await.unwrap().is_none());
        let inputs = q.inputs(&a.id).await.unwrap();
        assert_eq!(inputs.len(), 2);
        assert_eq!(inputs[0].role, "points");
        assert_eq!(inputs[1].role, "trajectory");
    }

    #[tokio::test]
    async fn expired_lease_is_reclaimed_and_the_stale_owner_is_fenced_out() {
        let (_d, q, clock) = setup().await;
        let job = q.enqueue(&new_job()).await.unwrap();
        q.claim("old", 1000).await.unwrap().unwrap();
        // Heartbeats keep the lease; without them it expires.
        clock.advance(900);
        q.heartbeat(&job.id, "old", 1000).await.unwrap();
        clock.advance(900);
        assert!(q.claim("new", 1000).await.unwrap().is_none(), "lease still held");
        clock.advance(200);
        let again = q.claim("new", 1000).await.unwrap().unwrap();
        assert_eq!(again.attempts, 2);
        // Every write of the old owner is rejected.
        assert!(matches!(
            q.heartbeat(&job.id, "old", 1000).await,
            Err(QueueError::LeaseLost { .. })
        ));
        assert!(matches!(
            q.set_progress(&job.id, "old", "x", 0.5).await,
            Err(QueueError::LeaseLost { .. })
        ));
        assert!(matches!(
            q.complete(&job.id, "old", "results/x").await,
            Err(QueueError::LeaseLost { .. })
        ));
        assert!(matches!(
            q.fail(&job.id, "old", "c", "m").await,
            Err(QueueError::LeaseLost { .. })
        ));
        q.complete(&job.id, "new", "results/y").await.unwrap();
        let done = q.get(&job.id).await.unwrap().unwrap();
        assert_eq!(done.status, JobStatus::Succeeded);
        assert_eq!(done.result_path.as_deref(), Some("results/y"));
        assert!(done.lease_owner.is_none());
        // A finished job cannot be written again, not even by its last owner.
        assert!(q.complete(&job.id, "new", "results/z").await.is_err());
    }

    #[tokio::test]
    async fn retries_wait_for_their_backoff_and_exhausted_crashes_fail() {
        let (_d, q, clock) = setup().await;
        let job = q.enqueue(&new_job()).await.unwrap();
        q.claim("w", 1000).await.unwrap().unwrap();
        q.retry_later(&job.id, "w", "io", "disk hiccup", 500)
            .await
            .unwrap();
        assert!(q.claim("w", 1000).await.unwrap().is_none(), "not due yet");
        clock.advance(500);
        let second = q.claim("w2", 1000).await.unwrap().unwrap();
        assert_eq!(second.attempts, 2);
        // Its worker dies: the lease expires on the last attempt, so the sweep fails it.
        clock.advance(1000);
        assert!(q.claim("w3", 1000).await.unwrap().is_none());
        assert_eq!(q.sweep().await.unwrap(), 1);
        let failed = q.get(&job.id).await.unwrap().unwrap();
        assert_eq!(failed.status, JobStatus::Failed);
        assert_eq!(failed.error_code.as_deref(), Some("worker-lost"));
    }

    #[tokio::test]
    async fn cancel_queued_at_once_running_by_request_and_release_keeps_attempts() {
        let (_d, q, _c) = setup().await;
        let a = q.enqueue(&new_job()).await.unwrap();
        let b = q.enqueue(&new_job()).await.unwrap();
        q.claim("w", 1000).await.unwrap().unwrap(); // a
        assert!(matches!(
            q.cancel(&b.id).await.unwrap(),
            CancelOutcome::Cancelled(_)
        ));
        assert!(matches!(
            q.cancel(&a.id).await.unwrap(),
            CancelOutcome::Requested(_)
        ));
        assert!(q.heartbeat(&a.id, "w", 1000).await.unwrap().cancel_requested);
        q.mark_cancelled(&a.id, "w").await.unwrap();
        assert!(matches!(
            q.cancel(&a.id).await.unwrap(),
            CancelOutcome::AlreadyFinished(_)
        ));
        assert!(matches!(q.cancel("nope").await.unwrap(), CancelOutcome::NotFound));

        let c = q.enqueue(&new_job()).await.unwrap();
        q.claim("w", 1000).await.unwrap().unwrap();
        q.release(&c.id, "w").await.unwrap();
        let released = q.get(&c.id).await.unwrap().unwrap();
        assert_eq!((released.status, released.attempts), (JobStatus::Queued, 0));
    }

    #[tokio::test]
    async fn listing_is_newest_first_with_a_keyset_cursor() {
        let (_d, q, _c) = setup().await;
        let mut ids = Vec::new();
        for _ in 0..5 {
            ids.push(q.enqueue(&new_job()).await.unwrap().id);
        }
        let page1 = q.list(None, None, 2).await.unwrap();
        assert_eq!(
            page1.iter().map(|j| &j.id).collect::<Vec<_>>(),
            vec![&ids[4], &ids[3]]
        );
        let page2 = q.list(None, Some(page1[1].seq), 10).await.unwrap();
        assert_eq!(page2.len(), 3);
        assert_eq!(page2[0].id, ids[2]);
        assert_eq!(q.list(Some(JobStatus::Running), None, 10).await.unwrap().len(), 0);
    }

    #[test]
    fn backoff_doubles_and_caps() {
        assert_eq!(backoff_ms(1, 100, 1000), 100);
        assert_eq!(backoff_ms(2, 100, 1000), 200);
        assert_eq!(backoff_ms(3, 100, 1000), 400);
        assert_eq!(backoff_ms(10, 100, 1000), 1000);
        assert_eq!(backoff_ms(1000, 100, 1000), 1000);
    }
}
