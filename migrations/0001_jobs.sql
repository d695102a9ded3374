-- roadmark service schema: uploaded files and the job queue.
-- Times are integer milliseconds since the Unix epoch, taken from the service clock
-- (injectable in tests), so lease arithmetic is plain integer comparison.

CREATE TABLE uploads (
    id          TEXT PRIMARY KEY,             -- uuid, also the file name on disk
    kind        TEXT NOT NULL CHECK (kind IN ('las', 'laz', 'trajectory')),
    filename    TEXT,                         -- what the client called it (display only, never a path)
    size        INTEGER NOT NULL,
    sha256      TEXT NOT NULL,
    path        TEXT NOT NULL,                -- relative to the data directory
    summary     TEXT NOT NULL,                -- JSON: point count/bounds/CRS or trajectory rows
    created_at  INTEGER NOT NULL
);

CREATE TABLE jobs (
    seq               INTEGER PRIMARY KEY AUTOINCREMENT,  -- creation order: claim order and list cursor
    id                TEXT NOT NULL UNIQUE,               -- uuid, the public id
    status            TEXT NOT NULL
                      CHECK (status IN ('queued', 'running', 'succeeded', 'failed', 'cancelled')),
    params            TEXT NOT NULL,                      -- resolved parameters (JSON, defaults filled in)
    created_at        INTEGER NOT NULL,
    updated_at        INTEGER NOT NULL,
    started_at        INTEGER,
    finished_at       INTEGER,
    run_after         INTEGER NOT NULL,                   -- not claimed before (retry backoff)
    attempts          INTEGER NOT NULL DEFAULT 0,         -- counted at claim
    max_attempts      INTEGER NOT NULL,
    lease_owner       TEXT,                               -- unique token of the claim holding the job
    lease_expires_at  INTEGER,
    cancel_requested  INTEGER NOT NULL DEFAULT 0,
    progress_stage    TEXT,
    progress_fraction REAL,
    error_code        TEXT,
    error_message     TEXT,
    result_path       TEXT                                -- relative to the data directory
);

-- Claiming scans queued jobs by run_after and running jobs by lease expiry.
CREATE INDEX jobs_claim ON jobs (status, run_after, seq);
CREATE INDEX jobs_lease ON jobs (status, lease_expires_at);

CREATE TABLE job_inputs (
    job_id     TEXT NOT NULL REFERENCES jobs (id) ON DELETE CASCADE,
    role       TEXT NOT NULL CHECK (role IN ('points', 'trajectory')),
    position   INTEGER NOT NULL,                          -- order of the tiles as given
    upload_id  TEXT NOT NULL REFERENCES uploads (id),
    PRIMARY KEY (job_id, role, position)
);
