-- Widen the stored time range per tag (`sample_bounds`) by `incoming_bounds` (tag, ts_min,
-- ts_max) of samples just inserted. Using the bounds of every incoming row, inserted or not,
-- keeps the table a superset, which is all samples_may_overlap needs.
INSERT INTO sample_bounds AS b (tag, ts_min, ts_max)
SELECT tag, ts_min, ts_max FROM incoming_bounds
ON CONFLICT (tag) DO UPDATE SET ts_min = least(b.ts_min, excluded.ts_min),
                                ts_max = greatest(b.ts_max, excluded.ts_max)
