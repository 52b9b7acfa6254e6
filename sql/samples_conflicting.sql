-- Incoming samples whose (tag, ts) is already stored with a different value or status.
-- (Same key and same value/status is an exact duplicate: the insert skips it.)
-- Reads the registered frame `incoming_samples`; $ts_min/$ts_max and the list $tags prune the scan.
SELECT i.source_line,
       i.tag,
       s.source_file AS stored_file,
       s.source_line AS stored_line
FROM incoming_samples AS i
JOIN samples AS s
  ON s.tag = i.tag AND s.ts = i.ts
WHERE s.ts BETWEEN $ts_min AND $ts_max
  AND s.tag = ANY($tags)
  AND (i.value IS DISTINCT FROM s.value OR i.status IS DISTINCT FROM s.status)
ORDER BY i.source_line
