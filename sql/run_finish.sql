UPDATE runs SET status = $status, finished_at = current_timestamp WHERE run_id = $run_id
