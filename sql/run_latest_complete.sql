-- The latest complete (or partial) run.
SELECT run_id FROM runs WHERE status IN ('complete', 'partial') ORDER BY started_at DESC, run_id DESC LIMIT 1
