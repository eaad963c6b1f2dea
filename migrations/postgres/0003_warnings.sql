-- What the 201 answer warned of (an import's approximations, what is valid but almost
-- surely a mistake, a bounce limit capped): a JSON array of strings, NULL when there is
-- nothing. Kept with the job so that every later reader (GET, the list, the stream, a
-- restart, any node) sees it too. SQLite's is migrations/0005_warnings.sql.
ALTER TABLE jobs ADD COLUMN warnings TEXT;
