-- Leases (shared/spec/cluster.md): a running job belongs to the worker holding its lease.
-- worker: the node name that holds (or last held) the job;
-- lease_token: the attempt's token; every write of that worker names it, so a worker
--   presumed dead (its lease expired and the job went elsewhere) can no longer write;
-- lease_expires_at: milliseconds since the Unix epoch on the database's clock.
ALTER TABLE jobs ADD COLUMN worker TEXT;
ALTER TABLE jobs ADD COLUMN lease_token TEXT;
ALTER TABLE jobs ADD COLUMN lease_expires_at BIGINT;
-- The reaper's scan: running jobs by expiry.
CREATE INDEX jobs_running_lease ON jobs (lease_expires_at) WHERE state = 'running';
