INSERT INTO verdicts BY NAME SELECT * FROM incoming_verdicts
