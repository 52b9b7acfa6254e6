-- Which of $tags have at least one sample in [start, end) (bounds may be NULL).
SELECT DISTINCT tag
FROM samples
WHERE list_contains($tags, tag)
  AND ($start::TIMESTAMPTZ IS NULL OR ts >= $start::TIMESTAMPTZ)
  AND ($end::TIMESTAMPTZ IS NULL OR ts < $end::TIMESTAMPTZ)
