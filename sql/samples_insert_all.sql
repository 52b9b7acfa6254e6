-- Insert every sample of `incoming_samples`: only when `samples_may_overlap` found that none of
-- their (tag, ts) keys can be stored yet.
-- The frame is sorted by (tag, ts) already (Store.insert_new_samples sees to it) and DuckDB keeps
-- the insertion order, so the rows land sorted without an ORDER BY (a sort here cost ~2.5x the
-- insert). $source_file, when not NULL, is the file of every row (the frame's column is then
-- empty: one bound text instead of the same text on every row).
INSERT INTO samples (tag, ts, value, status, source_file, source_line)
SELECT i.tag, i.ts, i.value, i.status, COALESCE($source_file::VARCHAR, i.source_file),
       i.source_line
FROM incoming_samples AS i
