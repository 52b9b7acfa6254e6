-- The latest complete run.
SELECT run_id FROM runs WHERE status = 'complete' ORDER BY started_at DESC, run_id DESC LIMIT 1
