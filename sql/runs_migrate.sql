-- Bring a runs table made before the owner/note columns, the 'aborted' or the 'partial'
-- status up to date (DuckDB cannot alter a CHECK constraint, so the table is rebuilt).
-- Run in one transaction by Store when sql/runs_current.sql says 0.
ALTER TABLE runs ADD COLUMN IF NOT EXISTS owner VARCHAR;
ALTER TABLE runs ADD COLUMN IF NOT EXISTS note VARCHAR;
ALTER TABLE runs RENAME TO runs_before_migration;
CREATE TABLE runs (
    run_id        VARCHAR PRIMARY KEY,
    started_at    TIMESTAMPTZ NOT NULL,
    finished_at   TIMESTAMPTZ,
    status        VARCHAR NOT NULL CHECK (status IN ('running', 'complete', 'partial', 'failed',
                                                     'aborted')),
    window_start  TIMESTAMPTZ,
    window_end    TIMESTAMPTZ,
    exports       VARCHAR,
    params        JSON,
    owner         VARCHAR,
    note          VARCHAR
);
INSERT INTO runs (run_id, started_at, finished_at, status, window_start, window_end, exports,
                  params, owner, note)
SELECT run_id, started_at, finished_at, status, window_start, window_end, exports, params,
       owner, note
FROM runs_before_migration;
DROP TABLE runs_before_migration;
