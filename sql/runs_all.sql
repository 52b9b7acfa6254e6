SELECT run_id, started_at, finished_at, status, window_start, window_end, exports, params, owner, note
FROM runs ORDER BY started_at, run_id
