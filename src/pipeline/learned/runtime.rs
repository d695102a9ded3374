//! Finding and loading the ONNX Runtime shared library.
//!
//! `ort` is built with `load-dynamic`: the library is opened at run time, not linked. Left to
//! itself `ort` panics on first use when the library is missing, so the pipeline always goes
//! through [`ensure_loaded`] first, which turns every failure into a [`PipelineError::Model`]
//! saying how to install the runtime.
//!
//! # Where the library is looked for, in this order
//! 1. `ORT_DYLIB_PATH` when set (exactly that file; no fallback, so a wrong setting is reported);
//! 2. `.venv-ort/lib/python3*/site-packages/onnxruntime/capi/libonnxruntime.so.*` under the
//!    working directory and under the executable's directory and its four parents (a
//!    `target/{debug,release}` build finds the repository's `.venv-ort`);
//! 3. `libonnxruntime.so*` next to the executable;
//! 4. `/usr/local/lib`, `/usr/lib`, `/usr/lib/x86_64-linux-gnu`, `/usr/lib/aarch64-linux-gnu`,
//!    `/opt/onnxruntime/lib`.
//!
//! The library is loaded once per process; later calls return the same path.

use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

use crate::pipeline::PipelineError;

/// The ONNX Runtime version `.ci/run` and the README install.
pub const ONNXRUNTIME_VERSION: &str = "1.31.1";

/// How to install the runtime; appended to every "not found" error.
pub const INSTALL_HINT: &str = "install ONNX Runtime with `python3 -m venv .venv-ort && \
     .venv-ort/bin/pip install --no-deps onnxruntime==1.31.1` in the directory you run roadmark \
     from (or the repository root), or set ORT_DYLIB_PATH to a libonnxruntime.so (version >= 1.17)";

/// What [`ensure_loaded`] found: the library path and the process-wide environment.
struct Loaded {
    path: PathBuf,
    env: ort::environment::Environment,
}

// SAFETY-free wrapper: `Environment` is an `Arc` over a thread-safe ONNX Runtime object.
static LOADED: OnceLock<Loaded> = OnceLock::new();
static LOADING: Mutex<()> = Mutex::new(());

/// Find, load and initialise ONNX Runtime once per process; returns the library's path.
pub fn ensure_loaded() -> Result<&'static Path, PipelineError> {
    environment().map(|l| l.path.as_path())
}

/// The process-wide ONNX Runtime environment (loading the library first if needed).
pub(crate) fn env() -> Result<&'static ort::environment::Environment, PipelineError> {
    environment().map(|l| &l.env)
}

fn environment() -> Result<&'static Loaded, PipelineError> {
    if let Some(l) = LOADED.get() {
        return Ok(l);
    }
    // Serialise first loads: ort allows one environment per process.
    let _guard = LOADING.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(l) = LOADED.get() {
        return Ok(l);
    }
    let path = locate(std::env::var_os("ORT_DYLIB_PATH").as_deref().map(Path::new))?;
    let loaded = load(&path)?;
    Ok(LOADED.get_or_init(|| loaded))
}

fn load(path: &Path) -> Result<Loaded, PipelineError> {
    let builder = ort::init_from(path).map_err(|e| {
        PipelineError::Model(format!(
            "cannot load the ONNX Runtime library {}: {e}; {INSTALL_HINT}",
            path.display()
        ))
    })?;
    let env = builder
        .with_name("roadmark")
        .with_telemetry(false)
        .build()
        .map_err(|e| {
            PipelineError::Model(format!("cannot start ONNX Runtime from {}: {e}", path.display()))
        })?;
    Ok(Loaded {
        path: path.to_path_buf(),
        env,
    })
}

/// Where the runtime library is, given the value of `ORT_DYLIB_PATH` (if any).
///
/// Does not load anything; fails with the list of places searched and the install hint.
pub fn locate(env_path: Option<&Path>) -> Result<PathBuf, PipelineError> {
    if let Some(p) = env_path.filter(|p| !p.as_os_str().is_empty()) {
        return if p.is_file() {
            Ok(p.to_path_buf())
        } else {
            Err(PipelineError::Model(format!(
                "ORT_DYLIB_PATH={} does not name a file (the ONNX Runtime library); {INSTALL_HINT}",
                p.display()
            )))
        };
    }
    let mut searched = Vec::new();
    let mut bases: Vec<PathBuf> = Vec::new();
    if let Ok(cwd) = std::env::current_dir() {
        bases.push(cwd);
    }
    let exe_dir = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf));
    if let Some(dir) = &exe_dir {
        bases.extend(dir.ancestors().take(5).map(Path::to_path_buf));
    }
    for base in &bases {
        let venv = base.join(".venv-ort");
        searched.push(venv.display().to_string());
        if let Some(p) = in_venv(&venv) {
            return Ok(p);
        }
    }
    let mut dirs: Vec<PathBuf> = exe_dir.into_iter().collect();
    dirs.extend(
        [
            "/usr/local/lib",
            "/usr/lib",
            "/usr/lib/x86_64-linux-gnu",
            "/usr/lib/aarch64-linux-gnu",
            "/opt/onnxruntime/lib",
        ]
        .iter()
        .map(PathBuf::from),
    );
    for dir in &dirs {
        searched.push(dir.display().to_string());
        if let Some(p) = newest_library_in(dir) {
            return Ok(p);
        }
    }
    Err(PipelineError::Model(format!(
        "the ONNX Runtime library (libonnxruntime.so) was not found; ORT_DYLIB_PATH is not set and \
         none is in {}; {INSTALL_HINT}",
        searched.join(", ")
    )))
}

/// The library inside a Python virtualenv with the `onnxruntime` wheel.
fn in_venv(venv: &Path) -> Option<PathBuf> {
    let lib = venv.join("lib");
    let mut pythons: Vec<PathBuf> = std::fs::read_dir(&lib)
        .ok()?
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with("python"))
        .map(|e| e.path())
        .collect();
    pythons.sort();
    pythons
        .iter()
        .rev()
        .find_map(|py| newest_library_in(&py.join("site-packages/onnxruntime/capi")))
}

/// `libonnxruntime.so` or the highest `libonnxruntime.so.X.Y.Z` in `dir`.
fn newest_library_in(dir: &Path) -> Option<PathBuf> {
    let mut found: Vec<(Vec<u32>, PathBuf)> = std::fs::read_dir(dir)
        .ok()?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let rest = name.strip_prefix("libonnxruntime.so")?;
            let version = if rest.is_empty() {
                Vec::new()
            } else {
                rest.strip_prefix('.')?
                    .split('.')
                    .map(|p| p.parse::<u32>().ok())
                    .collect::<Option<Vec<u32>>>()?
            };
            e.path().is_file().then(|| (version, e.path()))
        })
        .collect();
    found.sort();
    found.pop().map(|(_, p)| p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wrong_ort_dylib_path_is_a_clear_error() {
        let err = locate(Some(Path::new("/nonexistent/libonnxruntime.so.1"))).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("ORT_DYLIB_PATH=/nonexistent/libonnxruntime.so.1"),
            "{msg}"
        );
        assert!(msg.contains("pip install --no-deps onnxruntime==1.31.1"), "{msg}");
    }

    #[test]
    fn the_newest_library_of_a_directory_is_chosen() {
        let dir = tempfile::tempdir().unwrap();
        for name in [
            "libonnxruntime.so.1.9.0",
            "libonnxruntime.so.1.31.1",
            "libonnxruntime_providers_shared.so",
            "libonnxruntime.so.1.31.1.bak",
        ] {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        assert_eq!(
            newest_library_in(dir.path()).unwrap(),
            dir.path().join("libonnxruntime.so.1.31.1")
        );
        let venv = dir.path().join(".venv-ort");
        let capi = venv.join("lib/python3.11/site-packages/onnxruntime/capi");
        std::fs::create_dir_all(&capi).unwrap();
        assert!(in_venv(&venv).is_none());
        std::fs::write(capi.join("libonnxruntime.so.1.31.1"), b"").unwrap();
        assert_eq!(in_venv(&venv).unwrap(), capi.join("libonnxruntime.so.1.31.1"));
    }
}
