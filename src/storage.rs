//! On-disk layout of the data directory: database, uploads, results.
//!
//! ```text
//! <data-dir>/roadmark.db            SQLite (WAL) — uploads and the job queue
//! <data-dir>/tmp/<uuid>.part        uploads while they stream in (removed on any failure)
//! <data-dir>/uploads/<uuid>.<ext>   validated uploads (ext: las, laz, csv)
//! <data-dir>/results/<job>.<claim>.json  the Extraction of job <job>, written under claim <claim>
//! ```
//!
//! File names are generated here, never taken from a client, so no request can reach a path
//! outside the data directory. The database stores paths relative to the data directory.
//!
//! Results are written durably: temporary name, `fsync`, `rename`, `fsync` of the directory;
//! only then does the worker mark the job succeeded (a fenced update naming this file). Each
//! attempt writes its own file name, so a stale worker that lost its lease can never replace
//! the result that the database points to; it deletes its own orphan instead.
//!
//! One process per data directory: [`Storage::open`] clears unfinished temporary files.

use std::fs;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// Database file name inside the data directory.
pub const DATABASE_FILE: &str = "roadmark.db";

#[derive(Clone, Debug)]
pub struct Storage {
    root: PathBuf,
}

impl Storage {
    /// Create (if needed) the directory layout under `root` and clear leftovers of interrupted
    /// uploads and result writes.
    pub fn open(root: &Path) -> io::Result<Storage> {
        for sub in ["tmp", "uploads", "results"] {
            fs::create_dir_all(root.join(sub))?;
        }
        let storage = Storage {
            root: root.to_path_buf(),
        };
        storage.remove_leftovers()?;
        Ok(storage)
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn database_path(&self) -> PathBuf {
        self.root.join(DATABASE_FILE)
    }

    /// A fresh temporary path for an upload that is streaming in.
    pub fn temp_upload_path(&self) -> PathBuf {
        self.root
            .join("tmp")
            .join(format!("{}.part", uuid::Uuid::new_v4()))
    }

    /// Relative path of a validated upload.
    pub fn upload_rel(id: &str, ext: &str) -> String {
        format!("uploads/{id}.{ext}")
    }

    /// Relative path of the result written under one claim (`token`) of a job.
    pub fn result_rel(job_id: &str, token: &str) -> String {
        format!("results/{job_id}.{token}.json")
    }

    /// Absolute path of a relative path stored in the database.
    pub fn resolve(&self, rel: &str) -> PathBuf {
        self.root.join(rel)
    }

    /// Write `bytes` at `rel` durably: temp file, fsync, rename, fsync of the directory.
    pub fn write_durably(&self, rel: &str, bytes: &[u8]) -> io::Result<PathBuf> {
        let dest = self.resolve(rel);
        let dir = dest.parent().unwrap_or(&self.root).to_path_buf();
        let tmp = dir.join(format!(
            ".{}.tmp",
            dest.file_name().and_then(|n| n.to_str()).unwrap_or("result")
        ));
        let mut file = fs::File::create(&tmp)?;
        let written = file.write_all(bytes).and_then(|()| file.sync_all());
        if let Err(e) = written {
            let _ = fs::remove_file(&tmp);
            return Err(e);
        }
        drop(file);
        fs::rename(&tmp, &dest)?;
        sync_dir(&dir)?;
        Ok(dest)
    }

    /// Move a validated upload from its temporary path to its final place, durably.
    pub fn commit_upload(&self, temp: &Path, rel: &str) -> io::Result<PathBuf> {
        let dest = self.resolve(rel);
        fs::rename(temp, &dest)?;
        sync_dir(dest.parent().unwrap_or(&self.root))?;
        Ok(dest)
    }

    /// Remove a file if it exists (cleanup paths: a missing file is not an error).
    pub fn remove(&self, rel: &str) -> io::Result<()> {
        match fs::remove_file(self.resolve(rel)) {
            Err(e) if e.kind() != io::ErrorKind::NotFound => Err(e),
            _ => Ok(()),
        }
    }

    fn remove_leftovers(&self) -> io::Result<()> {
        for entry in fs::read_dir(self.root.join("tmp"))? {
            let path = entry?.path();
            if path.extension().is_some_and(|e| e == "part") {
                fs::remove_file(&path)?;
            }
        }
        for entry in fs::read_dir(self.root.join("results"))? {
            let path = entry?.path();
            if path.extension().is_some_and(|e| e == "tmp") {
                fs::remove_file(&path)?;
            }
        }
        Ok(())
    }
}

/// Make a rename durable: fsync the directory holding the new entry (a no-op where directories
/// cannot be opened, e.g. Windows).
fn sync_dir(dir: &Path) -> io::Result<()> {
    #[cfg(unix)]
    {
        fs::File::open(dir)?.sync_all()
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_and_durable_write() {
        let dir = tempfile::tempdir().unwrap();
        let s = Storage::open(dir.path()).unwrap();
        let rel = Storage::result_rel("job", "c1");
        let path = s.write_durably(&rel, b"{}").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"{}");
        assert!(path.starts_with(dir.path().join("results")));
        // No temporary file left behind, and overwrite works.
        s.write_durably(&rel, b"[]").unwrap();
        let names: Vec<_> = fs::read_dir(dir.path().join("results")).unwrap().collect();
        assert_eq!(names.len(), 1);
        s.remove(&rel).unwrap();
        s.remove(&rel).unwrap();
    }

    #[test]
    fn leftovers_are_cleared_on_open() {
        let dir = tempfile::tempdir().unwrap();
        let s = Storage::open(dir.path()).unwrap();
        let part = s.temp_upload_path();
        fs::write(&part, b"half").unwrap();
        fs::write(dir.path().join("results/.x.json.tmp"), b"half").unwrap();
        Storage::open(dir.path()).unwrap();
        assert!(!part.exists());
        assert!(!dir.path().join("results/.x.json.tmp").exists());
    }
}
