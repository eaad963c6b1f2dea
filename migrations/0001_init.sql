-- Glimpse job store, first schema (issue #5, service-api.md "Durability").
-- Timestamps are RFC 3339 UTC text; JSON columns hold serde_json text (NULL = absent).
-- Images live in files beside the database (data/jobs/<id>/), named from the id only.
CREATE TABLE jobs (
    id          TEXT PRIMARY KEY NOT NULL,   -- UUIDv7: sorts by creation time
    name        TEXT NOT NULL,
    state       TEXT NOT NULL CHECK (state IN ('queued', 'running', 'succeeded', 'failed', 'cancelled')),
    scene       TEXT NOT NULL,               -- the submitted document, re-parsed by the worker
    created_at  TEXT NOT NULL,
    started_at  TEXT,
    finished_at TEXT,
    progress    TEXT,
    stats       TEXT,
    error       TEXT,
    has_frame   INTEGER NOT NULL DEFAULT 0   -- 1 once image files exist under jobs/<id>/
);

CREATE INDEX jobs_state_id ON jobs (state, id);
