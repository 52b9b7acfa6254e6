-- Mark every run still 'running' as 'aborted' (their scans died: the caller holds the
-- store's scan lock) and return their ids.
UPDATE runs SET status = 'aborted', finished_at = current_timestamp, note = $note
WHERE status = 'running'
RETURNING run_id, owner
