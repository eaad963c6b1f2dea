-- What the 201 answer warned of (an import's approximations, what is valid but almost
-- surely a mistake, a bounce limit capped): a JSON array of strings, NULL when there is
-- nothing. Kept with the job so that every later reader (GET, the list, the stream, a
-- restart) sees it too. Numbered 0005 so that another branch's 0003 can land beside it.
ALTER TABLE jobs ADD COLUMN warnings TEXT;
