-- Bring a runs table made before the owner/note columns and the 'aborted' status up to
-- date (DuckDB cannot alter a CHECK constraint, so the table is rebuilt). Run in one
-- transaction by Store when runs has no owner column.
ALTER TABLE runs RENAME TO runs_before_migration;
CREATE TABLE runs (
    run_id        VARCHAR PRIMARY KEY,
    started_at    TIMESTAMPTZ NOT NULL,
    finished_at   TIMESTAMPTZ,
    status        VARCHAR NOT NULL CHECK (status IN ('running', 'complete', 'failed', 'aborted')),
    window_start  TIMESTAMPTZ,
    window_end    TIMESTAMPTZ,
    exports       VARCHAR,
    params        JSON,
    owner         VARCHAR,
    note          VARCHAR
);
INSERT INTO runs (run_id, started_at, finished_at, status, window_start, window_end, exports,
                  params)
SELECT run_id, started_at, finished_at, status, window_start, window_end, exports, params
FROM runs_before_migration;
DROP TABLE runs_before_migration;
