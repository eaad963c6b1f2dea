-- Issue 14: what must survive a crash besides the state.
-- attempts: how many times a worker started the job; counted (and committed) before the
--   render starts, so a job that took the server down twice is found at start-up and
--   failed as a poison job instead of being run again for ever.
-- cancel_requested: a cancel acknowledged with 202 while the job ran; a restart finishes
--   such a job as cancelled instead of running it again.
ALTER TABLE jobs ADD COLUMN attempts INTEGER NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN cancel_requested INTEGER NOT NULL DEFAULT 0;
