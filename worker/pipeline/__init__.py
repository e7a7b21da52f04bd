"""The processing pipeline as a plain library.

Nothing here imports FastAPI, Celery or SQLAlchemy: every stage is a function over
files and arrays with an options dataclass and a result dataclass, so the API, the
Celery tasks and the CLI all run the same code.
"""
