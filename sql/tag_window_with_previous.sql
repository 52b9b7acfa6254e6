-- Like tag_window, plus the last sample before $start (for held signals: SP, mode).
SELECT ts, value, status
FROM samples
WHERE tag = $tag
  AND ($start::TIMESTAMPTZ IS NULL OR ts >= $start::TIMESTAMPTZ)
  AND ($end::TIMESTAMPTZ IS NULL OR ts < $end::TIMESTAMPTZ)
UNION ALL
SELECT ts, value, status FROM (
    SELECT ts, value, status
    FROM samples
    WHERE tag = $tag AND $start::TIMESTAMPTZ IS NOT NULL AND ts < $start::TIMESTAMPTZ
    ORDER BY ts DESC
    LIMIT 1
)
ORDER BY ts
