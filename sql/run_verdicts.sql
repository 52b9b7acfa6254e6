-- Verdicts of one run; with $run_id NULL, of the latest complete (or partial) run.
SELECT v.*
FROM verdicts AS v
WHERE v.run_id = coalesce($run_id::VARCHAR, (
    SELECT run_id FROM runs WHERE status IN ('complete', 'partial')
    ORDER BY started_at DESC, run_id DESC LIMIT 1))
ORDER BY v.rank NULLS LAST, v.loop
