-- Insert the samples of `incoming_samples` whose (tag, ts) is not stored yet.
-- The bounds on ts and the list of incoming tags are pushed into the scan of `samples`
-- (zone maps; samples are inserted sorted by tag, ts), so the anti-join reads only the row
-- groups that may hold the incoming keys, not the whole table.
-- $source_file: as in samples_insert_all. The ORDER BY keeps the stored rows sorted (the
-- anti-join does not keep the frame's order); this path runs only when keys may be stored.
INSERT INTO samples (tag, ts, value, status, source_file, source_line)
SELECT i.tag, i.ts, i.value, i.status, COALESCE($source_file::VARCHAR, i.source_file),
       i.source_line
FROM incoming_samples AS i
WHERE NOT EXISTS (
    SELECT 1 FROM samples AS s
    WHERE s.tag = i.tag AND s.ts = i.ts AND s.ts BETWEEN $ts_min AND $ts_max
      AND s.tag = ANY($tags)
)
ORDER BY i.tag, i.ts
