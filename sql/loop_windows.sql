-- The samples of a group of loops over their windows, one query for the group.
-- export_jobs (registered frame): job, role, tag, w_start, w_end, held.
-- Every (job, role) gets its samples in [w_start, w_end), and a held role (set point,
-- mode) also its last sample before w_start. The tag lists and time bounds are
-- literal filters so that DuckDB skips row groups by their statistics.
SELECT j.job, j.role, s.ts, s.value, s.status
FROM samples AS s JOIN export_jobs AS j
  ON s.tag = j.tag AND s.ts >= j.w_start AND s.ts < j.w_end
WHERE list_contains($tags, s.tag) AND s.ts >= $t0 AND s.ts < $t1
UNION ALL
SELECT j.job, j.role, s.ts, s.value, s.status
FROM samples AS s JOIN export_jobs AS j
  ON s.tag = j.tag AND s.ts < j.w_start AND j.held
WHERE list_contains($held_tags, s.tag) AND s.ts < $t_held
QUALIFY row_number() OVER (PARTITION BY j.job, j.role ORDER BY s.ts DESC) = 1
