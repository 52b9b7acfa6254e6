-- When run $run_id started (no row when it is not in the store).
SELECT started_at FROM runs WHERE run_id = $run_id
