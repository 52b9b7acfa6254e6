"""The DuckDB schema and the named queries of valvediag.store, shipped inside the package."""
