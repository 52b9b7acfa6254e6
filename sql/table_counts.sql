SELECT
    (SELECT count(*) FROM samples)        AS samples,
    (SELECT count(*) FROM quarantine)     AS quarantine,
    (SELECT count(*) FROM ingested_files) AS ingested_files,
    (SELECT count(*) FROM loops)          AS loops,
    (SELECT count(*) FROM runs)           AS runs,
    (SELECT count(*) FROM episodes)       AS episodes,
    (SELECT count(*) FROM verdicts)       AS verdicts
