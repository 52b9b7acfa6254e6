-- Loops whose verdict in run $run_id is a fault (one of $faults, valvediag.verdicts.FAULT_VERDICTS) and was not a fault in the latest complete
-- (or partial) run before it (a loop absent from that run, or no earlier such run, counts as new).
-- Works while $run_id is still running, so the nightly flow can report it before closing.
WITH this_run AS (
    SELECT started_at FROM runs WHERE run_id = $run_id
),
previous_run AS (
    SELECT r.run_id
    FROM runs AS r, this_run AS t
    WHERE r.status IN ('complete', 'partial') AND r.run_id <> $run_id AND r.started_at <= t.started_at
    ORDER BY r.started_at DESC, r.run_id DESC
    LIMIT 1
),
current_verdicts AS (
    SELECT * FROM verdicts WHERE run_id = $run_id
),
previous AS (
    SELECT v.loop, v.verdict FROM verdicts AS v JOIN previous_run USING (run_id)
)
SELECT c.run_id, c.loop, c.verdict, c.confidence, c.rank, c.severity, c.bi, c.reason,
       p.verdict AS previous_verdict
FROM current_verdicts AS c
LEFT JOIN previous AS p USING (loop)
WHERE list_contains($faults, c.verdict)
  AND (p.verdict IS NULL OR NOT list_contains($faults, p.verdict))
ORDER BY c.rank NULLS LAST, c.loop
