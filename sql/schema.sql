-- valvediag store schema (DuckDB). Loaded by valvediag.store.Store on open.
-- All time stamps are TIMESTAMPTZ in UTC; the connection runs with TimeZone='UTC'.

-- One row per historian sample. (tag, ts) is unique: the ingest enforces it with
-- an anti-join inside one transaction per file (the store is single-writer).
-- There is deliberately no PRIMARY KEY: DuckDB keeps an ART index for it that,
-- measured on 3 M rows, made inserts ~5x slower and the file ~9x larger.
-- value IS NULL means a bad sample (a digital state); its text is in status.
CREATE TABLE IF NOT EXISTS samples (
    tag          VARCHAR     NOT NULL,
    ts           TIMESTAMPTZ NOT NULL,
    value        DOUBLE,
    status       VARCHAR,
    source_file  VARCHAR     NOT NULL,
    source_line  BIGINT      NOT NULL
);

-- Per tag, the time range of its stored samples: a superset kept up to date by every insert
-- into samples (sql/samples_bounds_update.sql, same transaction). It lets the ingest see in
-- a table of one row per tag that incoming samples cannot clash with stored ones, instead of
-- scanning samples, whose zone maps on VARCHAR tags hold 8-byte prefixes only
-- ("LIC1000.PV" vs "LIC1000.OP"): ~140 ms per slice at 149 M rows. A store made before this
-- table existed gets it filled on open (sql/samples_bounds_rebuild.sql).
CREATE TABLE IF NOT EXISTS sample_bounds (
    tag     VARCHAR     PRIMARY KEY,
    ts_min  TIMESTAMPTZ NOT NULL,
    ts_max  TIMESTAMPTZ NOT NULL
);

-- Rows that could not be used, with the raw text and why.
CREATE TABLE IF NOT EXISTS quarantine (
    source_file  VARCHAR     NOT NULL,
    line         BIGINT      NOT NULL,
    raw          VARCHAR,
    reason       VARCHAR     NOT NULL,
    ingested_at  TIMESTAMPTZ NOT NULL DEFAULT current_timestamp,
    PRIMARY KEY (source_file, line, reason)
);

-- Every export file read, by content hash.
CREATE TABLE IF NOT EXISTS ingested_files (
    path           VARCHAR     NOT NULL,
    sha256         VARCHAR     NOT NULL,
    rows           BIGINT      NOT NULL,   -- samples parsed (after in-file de-duplication)
    rows_inserted  BIGINT      NOT NULL,   -- new samples stored
    duplicates     BIGINT      NOT NULL,   -- exact duplicates skipped (in file + already stored)
    quarantined    BIGINT      NOT NULL,   -- quarantine rows of this file
    ingested_at    TIMESTAMPTZ NOT NULL DEFAULT current_timestamp,
    PRIMARY KEY (path, sha256)
);

-- The loop registry (loops.csv).
CREATE TABLE IF NOT EXISTS loops (
    loop          VARCHAR PRIMARY KEY,
    pv_tag        VARCHAR,
    op_tag        VARCHAR,
    sp_tag        VARCHAR,
    mv_tag        VARCHAR,
    mode_tag      VARCHAR,
    process_type  VARCHAR NOT NULL DEFAULT 'unknown'
                  CHECK (process_type IN ('integrating', 'self-regulating', 'unknown')),
    unit          VARCHAR,
    span          DOUBLE,
    criticality   DOUBLE  NOT NULL DEFAULT 1.0,
    description   VARCHAR,
    issues        VARCHAR[],
    sampling      VARCHAR DEFAULT 'point'
);
-- A store made before loops.sampling gets it; its loops read as 'point', as they were.
ALTER TABLE loops ADD COLUMN IF NOT EXISTS sampling VARCHAR DEFAULT 'point';

-- One row per scan. Runs 'complete' or 'partial' (every step ran, but some export could not
-- be read or stored nothing: note names them) count as history. 'aborted': the scan's
-- process died (found by the next scan, which holds the store's scan lock; see
-- valvediag.store.lock). owner is pid@host of the scan's process, note says why a run is
-- partial, failed or was aborted.
-- (A store made before owner/note or 'partial' existed is migrated on open:
-- sql/runs_migrate.sql.)
CREATE TABLE IF NOT EXISTS runs (
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

-- Oscillation episodes found by a run.
CREATE TABLE IF NOT EXISTS episodes (
    run_id      VARCHAR NOT NULL,
    loop        VARCHAR NOT NULL,
    start_ts    TIMESTAMPTZ,
    end_ts      TIMESTAMPTZ,
    period_s    DOUBLE,
    amplitude   DOUBLE,
    regularity  DOUBLE,
    verdict     VARCHAR,
    bi          DOUBLE,
    confidence  DOUBLE
);

-- One verdict per loop and run.
CREATE TABLE IF NOT EXISTS verdicts (
    run_id        VARCHAR NOT NULL,
    loop          VARCHAR NOT NULL,
    verdict       VARCHAR NOT NULL CHECK (verdict IN (
                      'insufficient-data', 'no-oscillation', 'not-integrating',
                      'linear-oscillation', 'stiction', 'backlash', 'undecided')),
    confidence    DOUBLE,
    rank          INTEGER,
    severity      DOUBLE,
    process_type  VARCHAR,
    bi            DOUBLE,
    period_s      DOUBLE,
    amplitude     DOUBLE,
    regularity    DOUBLE,
    reason        VARCHAR,
    evidence      JSON,
    quality       JSON,
    PRIMARY KEY (run_id, loop)
);
