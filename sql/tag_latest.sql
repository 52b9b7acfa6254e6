-- Latest time stamp per tag (any sample) and latest good sample.
SELECT tag,
       max(ts)                                  AS last_ts,
       max(ts) FILTER (WHERE value IS NOT NULL) AS last_good_ts,
       count(*)                                 AS rows
FROM samples
GROUP BY tag
ORDER BY tag
