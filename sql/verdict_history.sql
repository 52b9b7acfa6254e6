-- One loop's verdicts over all complete (or partial) runs, oldest first.
SELECT r.run_id, r.started_at, r.window_start, r.window_end,
       v.verdict, v.confidence, v.rank, v.severity, v.bi, v.period_s, v.amplitude,
       v.regularity, v.reason
FROM verdicts AS v
JOIN runs AS r USING (run_id)
WHERE r.status IN ('complete', 'partial') AND v.loop = $loop
ORDER BY r.started_at, r.run_id
