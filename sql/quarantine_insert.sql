-- Add the rows of `incoming_quarantine`; a row already quarantined is kept as is.
INSERT INTO quarantine (source_file, line, raw, reason, ingested_at)
SELECT source_file, line, raw, reason, current_timestamp
FROM incoming_quarantine
ON CONFLICT DO NOTHING
