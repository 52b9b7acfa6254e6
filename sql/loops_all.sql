-- Every column: a store opened read-only that was made before loops.sampling lacks it.
SELECT *
FROM loops
ORDER BY loop
