INSERT INTO runs (run_id, started_at, status, window_start, window_end, exports, params, owner)
VALUES ($run_id, current_timestamp, 'running', $window_start, $window_end, $exports, $params,
        $owner)
