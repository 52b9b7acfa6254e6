DELETE FROM verdicts WHERE run_id = $run_id
