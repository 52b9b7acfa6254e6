SELECT count(*) > 0 AS known FROM ingested_files WHERE sha256 = $sha256
