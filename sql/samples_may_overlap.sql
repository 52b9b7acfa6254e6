-- Could any (tag, ts) of `incoming_samples` be stored already? True when a stored sample of an
-- incoming tag lies within that tag's incoming time range (`incoming_bounds`: tag, ts_min,
-- ts_max). A cheap pre-check: the list $tags is pushed into the scan of `samples`, so only row
-- groups that may hold those tags are read. When it is false (new tags, a new day of known
-- tags, the next slice of a file: the usual case) the ingest inserts without the anti-join,
-- whose hash join costs time and memory growing with the whole table.
SELECT EXISTS (
    SELECT 1
    FROM samples AS s
    JOIN incoming_bounds AS b
      ON s.tag = b.tag AND s.ts BETWEEN b.ts_min AND b.ts_max
    WHERE s.tag = ANY($tags)
) AS may_overlap
