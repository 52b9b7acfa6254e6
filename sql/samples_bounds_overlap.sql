-- Can any (tag, ts) of `incoming_bounds` (tag, ts_min, ts_max) be stored already, judged by the
-- per-tag stored time ranges of `sample_bounds` (one row per tag, a superset)? False settles it
-- without reading samples; true is followed by the exact check samples_may_overlap.
SELECT EXISTS (
    SELECT 1
    FROM sample_bounds AS r
    JOIN incoming_bounds AS b
      ON r.tag = b.tag AND r.ts_min <= b.ts_max AND b.ts_min <= r.ts_max
) AS may_overlap
