SELECT source_file, line, raw, reason, ingested_at
FROM quarantine
WHERE $source_file::VARCHAR IS NULL OR source_file = $source_file
ORDER BY source_file, line, reason
