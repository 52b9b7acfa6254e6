SELECT * FROM episodes WHERE run_id = $run_id ORDER BY loop, start_ts
