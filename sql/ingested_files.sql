SELECT path, sha256, rows, rows_inserted, duplicates, quarantined, ingested_at
FROM ingested_files
ORDER BY ingested_at, path
