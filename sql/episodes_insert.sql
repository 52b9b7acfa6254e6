INSERT INTO episodes BY NAME SELECT * FROM incoming_episodes
