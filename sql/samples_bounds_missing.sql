-- True when the store has no `sample_bounds` table yet (made before it existed): the store then
-- fills it from samples once (samples_bounds_rebuild) after creating it.
SELECT count(*) = 0 AS missing
FROM duckdb_tables()
WHERE table_name = 'sample_bounds' AND schema_name = current_schema()
