-- Insert the samples of `incoming_samples` whose (tag, ts) is not stored yet.
-- The bounds on ts and the list of incoming tags are pushed into the scan of `samples`
-- (zone maps; samples are inserted sorted by tag, ts), so the anti-join reads only the row
-- groups that may hold the incoming keys, not the whole table.
INSERT INTO samples (tag, ts, value, status, source_file, source_line)
SELECT i.tag, i.ts, i.value, i.status, i.source_file, i.source_line
FROM incoming_samples AS i
WHERE NOT EXISTS (
    SELECT 1 FROM samples AS s
    WHERE s.tag = i.tag AND s.ts = i.ts AND s.ts BETWEEN $ts_min AND $ts_max
      AND s.tag = ANY($tags)
)
ORDER BY i.tag, i.ts
