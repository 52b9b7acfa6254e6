INSERT INTO loops BY NAME SELECT * FROM incoming_loops
