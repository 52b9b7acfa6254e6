INSERT OR REPLACE INTO ingested_files
    (path, sha256, rows, rows_inserted, duplicates, quarantined, ingested_at)
VALUES ($path, $sha256, $rows, $rows_inserted, $duplicates, $quarantined, current_timestamp)
