SELECT run_id, started_at, finished_at, status, window_start, window_end, exports, params, owner, note
FROM runs WHERE run_id = $run_id
