-- Number of (tag, ts) keys stored more than once; the ingest keeps this at 0.
SELECT count(*) AS n FROM (SELECT tag, ts FROM samples GROUP BY tag, ts HAVING count(*) > 1)
