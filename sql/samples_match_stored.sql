-- Incoming samples whose (tag, ts) is already stored, and whether value and status agree.
-- Reads the registered frame `incoming_samples`; $ts_min/$ts_max prune by zone maps.
SELECT i.source_line,
       i.tag,
       (i.value IS NOT DISTINCT FROM s.value AND i.status IS NOT DISTINCT FROM s.status) AS same,
       s.source_file AS stored_file,
       s.source_line AS stored_line
FROM incoming_samples AS i
JOIN samples AS s
  ON s.tag = i.tag AND s.ts = i.ts
WHERE s.ts BETWEEN $ts_min AND $ts_max
