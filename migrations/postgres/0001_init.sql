-- Glimpse job store on PostgreSQL (shared/spec/cluster.md): the same columns as the
-- SQLite store after its migrations 0001 and 0002, so one set of statements serves both.
-- Timestamps are RFC 3339 UTC text (fixed width: string order is time order); JSON
-- columns hold serde_json text (NULL = absent); integers are 64-bit.
CREATE TABLE jobs (
    id               TEXT PRIMARY KEY NOT NULL,   -- UUIDv7: sorts by creation time
    name             TEXT NOT NULL,
    state            TEXT NOT NULL CHECK (state IN ('queued', 'running', 'succeeded', 'failed', 'cancelled')),
    scene            TEXT NOT NULL,               -- the submitted document, re-parsed by the worker
    created_at       TEXT NOT NULL,
    started_at       TEXT,
    finished_at      TEXT,
    progress         TEXT,
    stats            TEXT,
    error            TEXT,
    has_frame        BIGINT NOT NULL DEFAULT 0,   -- 1 once the final image is stored
    attempts         BIGINT NOT NULL DEFAULT 0,   -- starts of the job, counted before its render
    cancel_requested BIGINT NOT NULL DEFAULT 0    -- a cancel acknowledged with 202
);

CREATE INDEX jobs_state_id ON jobs (state, id);
