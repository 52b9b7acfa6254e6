-- 1 when the runs table has the owner column (a store of the current schema), else 0.
SELECT count(*) AS n FROM information_schema.columns
WHERE table_name = 'runs' AND column_name = 'owner' AND table_schema = current_schema()
