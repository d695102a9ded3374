//! Pipeline errors. Input errors are fatal (retrying cannot help) and name the file;
//! I/O errors are retryable.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The input file is wrong or broken: fatal, never retried.
    #[error("{path}: {message}")]
    Input { path: PathBuf, message: String },
    /// Parameters failed validation.
    #[error("invalid parameters: {0}")]
    Params(String),
    /// Reading or writing failed for a reason outside the data (disk, permissions): retryable.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The job was cancelled at a stage boundary.
    #[error("cancelled")]
    Cancelled,
    /// The learned classifier could not be loaded or run.
    #[error("classifier: {0}")]
    Model(String),
    #[error("internal error: {0}")]
    Internal(String),
}

impl PipelineError {
    pub fn input(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        PipelineError::Input {
            path: path.into(),
            message: message.into(),
        }
    }

    /// Whether retrying the same job could succeed.
    pub fn is_retryable(&self) -> bool {
        matches!(self, PipelineError::Io { .. })
    }
}
