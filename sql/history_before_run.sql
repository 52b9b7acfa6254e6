-- Every loop's verdicts in the latest $max_runs complete (or partial) runs that started before run $run_id,
-- oldest first: the history the report and the work orders compare against. When $run_id is
-- not in the store, every complete (or partial) run counts. $run_id itself is never included.
WITH this_run AS (
    SELECT started_at FROM runs WHERE run_id = $run_id
),
earlier AS (
    SELECT r.run_id, r.started_at, r.window_end
    FROM runs AS r
    WHERE r.status IN ('complete', 'partial') AND r.run_id <> $run_id
      AND (NOT EXISTS (SELECT 1 FROM this_run)
           OR r.started_at <= (SELECT started_at FROM this_run))
    ORDER BY r.started_at DESC, r.run_id DESC
    LIMIT $max_runs
)
SELECT v.loop, e.run_id, e.started_at, e.window_end, v.verdict, v.confidence, v.bi, v.rank
FROM verdicts AS v
JOIN earlier AS e USING (run_id)
ORDER BY v.loop, e.started_at, e.run_id
