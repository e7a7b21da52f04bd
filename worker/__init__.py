"""Processing side of slidewatch.

`worker.pipeline` is the science as a plain library (paths and arrays in, files and
dataclasses out); `worker.simulator` makes synthetic surveys with known truth;
`worker.tasks` holds the thin Celery adapters that run pipeline stages for jobs.
"""
