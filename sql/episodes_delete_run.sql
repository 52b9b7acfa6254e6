DELETE FROM episodes WHERE run_id = $run_id
