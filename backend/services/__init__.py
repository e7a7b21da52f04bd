"""Use cases behind the API routes: each keeps the database and the files consistent."""
