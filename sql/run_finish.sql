UPDATE runs SET status = $status, finished_at = current_timestamp, note = coalesce($note, note)
WHERE run_id = $run_id
