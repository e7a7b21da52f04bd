"""Jobs: the database-backed state machine that runs pipeline stages one task at a time.

`runner` claims and runs one stage, `recovery` requeues stages whose worker died, and each
job kind (e.g. `comparison`) says which stages it has and how their results are stored.
"""
