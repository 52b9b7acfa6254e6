-- Fill `sample_bounds` from the stored samples (one pass over samples; run once per store).
INSERT OR REPLACE INTO sample_bounds (tag, ts_min, ts_max)
SELECT tag, min(ts), max(ts) FROM samples GROUP BY tag
