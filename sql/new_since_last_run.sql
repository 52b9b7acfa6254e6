-- Loops whose verdict in the latest complete run is a fault and was not a fault in the
-- previous complete run (a loop absent from that run, or a first complete run, counts as new).
WITH complete AS (
    SELECT run_id, row_number() OVER (ORDER BY started_at DESC, run_id DESC) AS k
    FROM runs WHERE status = 'complete'
),
latest AS (
    SELECT v.* FROM verdicts AS v JOIN complete AS c USING (run_id) WHERE c.k = 1
),
previous AS (
    SELECT v.loop, v.verdict FROM verdicts AS v JOIN complete AS c USING (run_id) WHERE c.k = 2
)
SELECT l.run_id, l.loop, l.verdict, l.confidence, l.rank, l.severity, l.bi, l.reason,
       p.verdict AS previous_verdict
FROM latest AS l
LEFT JOIN previous AS p USING (loop)
WHERE l.verdict IN ('stiction', 'backlash', 'linear-oscillation')
  AND (p.verdict IS NULL OR p.verdict NOT IN ('stiction', 'backlash', 'linear-oscillation'))
ORDER BY l.rank NULLS LAST, l.loop
