-- 1 when the runs table is of the current schema (owner and note columns, and the
-- 'partial' status allowed), else 0: Store then runs sql/runs_migrate.sql.
SELECT (SELECT count(*) FROM information_schema.columns
        WHERE table_name = 'runs' AND column_name = 'owner'
          AND table_schema = current_schema()) > 0
   AND (SELECT count(*) FROM duckdb_constraints()
        WHERE table_name = 'runs' AND constraint_type = 'CHECK'
          AND schema_name = current_schema()
          AND constraint_text LIKE '%''partial''%') > 0 AS n
