-- One tag's samples in [start, end); either bound may be NULL (open).
SELECT ts, value, status
FROM samples
WHERE tag = $tag
  AND ($start::TIMESTAMPTZ IS NULL OR ts >= $start::TIMESTAMPTZ)
  AND ($end::TIMESTAMPTZ IS NULL OR ts < $end::TIMESTAMPTZ)
ORDER BY ts
