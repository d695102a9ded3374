//! Start-up and graceful shutdown: HTTP server and workers in one process.
//!
//! [`Application::build`] opens the data directory and database (running migrations), builds
//! the rayon pool and binds the listener — port 0 gives a free port, which the tests use.
//! [`Application::run_until_stopped`] serves until its `shutdown` future resolves, then:
//! 1. stops accepting connections and lets in-flight requests finish;
//! 2. stops the workers from claiming, and asks running jobs to stop at their next stage
//!    boundary; they are released back to the queue (not failed) for the next start;
//! 3. waits up to `shutdown_grace_ms` for that. A job that does not reach a boundary in time
//!    keeps its lease until it expires and is then picked up again: nothing is lost.
//!
//! Dropping the `run_until_stopped` future instead (a crash, in tests) aborts workers on the
//! spot; their jobs are recovered by lease expiry.

use super::{ApiSettings, AppState};
use crate::config::Config;
use crate::jobs::worker::{WorkerContext, WorkerSettings, run_worker};
use crate::jobs::{Clock, PipelineRunner, Queue, Runner, SystemClock};
use crate::storage::Storage;
use anyhow::Context;
use std::future::{Future, IntoFuture};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::Notify;
use tokio::task::JoinSet;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

pub struct Application {
    listener: TcpListener,
    state: AppState,
    workers: Arc<WorkerContext>,
    config: Config,
}

impl Application {
    /// The shipped service: the real pipeline and the system clock.
    pub async fn build(config: Config) -> anyhow::Result<Application> {
        Application::build_with(config, Arc::new(PipelineRunner), Arc::new(SystemClock)).await
    }

    /// The service with another runner or clock (tests).
    pub async fn build_with(
        config: Config,
        runner: Arc<dyn Runner>,
        clock: Arc<dyn Clock>,
    ) -> anyhow::Result<Application> {
        config.validate().map_err(anyhow::Error::msg)?;
        let storage = Storage::open(&config.data_dir)
            .with_context(|| format!("preparing the data directory {}", config.data_dir.display()))?;
        let queue = Queue::connect(&storage.database_path(), clock)
            .await
            .with_context(|| format!("opening the database {}", storage.database_path().display()))?;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(config.pool_threads())
            .thread_name(|i| format!("roadmark-pipeline-{i}"))
            .build()
            .context("starting the pipeline thread pool")?;
        let listener = TcpListener::bind(config.bind)
            .await
            .with_context(|| format!("binding {}", config.bind))?;
        let wake = Arc::new(Notify::new());
        let state = AppState {
            queue: queue.clone(),
            storage: storage.clone(),
            settings: ApiSettings {
                max_upload_bytes: config.max_upload_bytes,
                max_attempts: config.max_attempts,
            },
            wake: wake.clone(),
        };
        let workers = Arc::new(WorkerContext {
            queue,
            storage,
            runner,
            pool: Arc::new(pool),
            settings: WorkerSettings::from_config(&config),
            wake,
        });
        Ok(Application {
            listener,
            state,
            workers,
            config,
        })
    }

    pub fn local_addr(&self) -> SocketAddr {
        self.listener.local_addr().unwrap_or(self.config.bind)
    }

    pub fn state(&self) -> &AppState {
        &self.state
    }

    /// The workers' shared context (tests drive single jobs through it).
    pub fn worker_context(&self) -> Arc<WorkerContext> {
        self.workers.clone()
    }

    /// Serve HTTP and run the workers until `shutdown` resolves, then stop gracefully.
    pub async fn run_until_stopped(
        self,
        shutdown: impl Future<Output = ()> + Send + 'static,
    ) -> anyhow::Result<()> {
        let Application {
            listener,
            state,
            workers: ctx,
            config,
        } = self;
        let token = CancellationToken::new();
        // Owned here: dropping this future aborts every worker (see the module docs).
        let mut workers = JoinSet::new();
        for i in 0..config.workers {
            workers.spawn(run_worker(ctx.clone(), format!("worker-{i}"), token.clone()));
        }
        info!(
            addr = %listener.local_addr().unwrap_or(config.bind),
            workers = config.workers,
            threads = config.pool_threads(),
            data_dir = %config.data_dir.display(),
            "roadmark service started"
        );
        let grace = Duration::from_millis(config.shutdown_grace_ms);
        let serve = axum::serve(listener, super::app(state.clone()))
            .with_graceful_shutdown(token.clone().cancelled_owned())
            .into_future();
        let mut serve = std::pin::pin!(serve);
        let mut shutdown = std::pin::pin!(shutdown);
        let served = tokio::select! {
            r = &mut serve => r.context("the HTTP server stopped"),
            () = &mut shutdown => {
                info!("shutdown requested: draining requests, stopping jobs at their next stage boundary");
                token.cancel();
                match tokio::time::timeout(grace, &mut serve).await {
                    Ok(r) => r.context("the HTTP server stopped"),
                    Err(_) => {
                        warn!("open connections did not finish within the grace period");
                        Ok(())
                    }
                }
            }
        };
        token.cancel();
        let drained =
            tokio::time::timeout(grace, async { while workers.join_next().await.is_some() {} }).await;
        if drained.is_err() {
            warn!(
                "jobs still running after the grace period; they are picked up again once their lease expires"
            );
        }
        state.queue.close().await;
        info!("roadmark service stopped");
        served
    }
}
