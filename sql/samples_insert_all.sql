-- Insert every sample of `incoming_samples`: only when `samples_may_overlap` found that none of
-- their (tag, ts) keys can be stored yet.
INSERT INTO samples (tag, ts, value, status, source_file, source_line)
SELECT i.tag, i.ts, i.value, i.status, i.source_file, i.source_line
FROM incoming_samples AS i
ORDER BY i.tag, i.ts
