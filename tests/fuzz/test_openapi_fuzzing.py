"""Every operation of the OpenAPI schema, fuzzed: no answer may be a server error.

Schemathesis draws requests from the schema itself (valid ones, and ones that break it:
wrong types, missing fields, huge numbers, odd strings), with an administrator's token so
that every route is reached, against one app on PostgreSQL with rows to find. The only
check is that the answer is not a 5xx: whatever a client sends, it gets a 4xx that says
what is wrong, or the answer it asked for.

Each operation gets Schemathesis's explicit cases (boundaries of every parameter: the
largest integers, empty and missing values, methods the route does not have) and then
FUZZ_EXAMPLES generated ones. Deterministic (hypothesis derandomized, no example
database), and bounded so that it stays within the suite's time.
"""

import json
import os
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest
import schemathesis
from fastapi import FastAPI
from hypothesis import HealthCheck, Phase, settings
from schemathesis.checks import not_a_server_error

from backend.api.app import create_app
from backend.config import Settings
from tests.monitoring_helpers import LiveServer

FUZZ_EXAMPLES = 10
SUMMARY = Path(__file__).resolve().parents[2] / "test-artifacts" / "fuzz-summary.json"
PARTS = SUMMARY.parent / "fuzz-parts"
# Raw uploads (a DSM, a tus chunk) are bytes like application/octet-stream.
schemathesis.serializer.alias(
    ["image/tiff", "application/offset+octet-stream"], "application/octet-stream"
)


def _schema() -> schemathesis.BaseSchema:
    """The schema as the app publishes it (an app made for it alone: no database needed)."""
    with tempfile.TemporaryDirectory(prefix="slidewatch-schema-") as folder:
        document = create_app(Settings(data_dir=Path(folder) / "data")).openapi()
    return schemathesis.openapi.from_dict(document)


SCHEMA = _schema()


_statuses: Counter[int] = Counter()
_operations: set[str] = set()


@pytest.fixture(scope="module")
def fuzz_server(fuzz_app: FastAPI) -> Iterator[str]:
    """The seeded app served over HTTP, as clients reach it: its base URL. When the run
    ends, what it did goes to test-artifacts/fuzz-summary.json (operations, cases, the
    statuses answered), over every test process of the run."""
    started = time.monotonic()
    with LiveServer(fuzz_app) as server:
        yield server.url
    _write_summary(time.monotonic() - started)


def _write_summary(seconds: float) -> None:
    """This process's share of the cases into test-artifacts/fuzz-parts/, then the summary
    of every share of this run (pytest-xdist splits the operations between processes; the
    last one to finish writes the whole)."""
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID", "one process")
    PARTS.mkdir(parents=True, exist_ok=True)
    part = {
        "run": run,
        "operations": sorted(_operations),
        "statuses": {str(k): v for k, v in _statuses.items()},
        "seconds": round(seconds, 1),
    }
    name = os.environ.get("PYTEST_XDIST_WORKER", "main")
    (PARTS / f"{name}.json").write_text(json.dumps(part) + "\n")
    shares = [json.loads(p.read_text()) for p in sorted(PARTS.glob("*.json"))]
    shares = [share for share in shares if share["run"] == run]
    statuses: Counter[int] = Counter()
    for share in shares:
        statuses.update({int(k): v for k, v in share["statuses"].items()})
    summary = {
        "operations": len({op for share in shares for op in share["operations"]}),
        "cases": sum(statuses.values()),
        "server_errors": sum(n for status, n in statuses.items() if status >= 500),
        "statuses": dict(sorted(statuses.items())),
        "seconds": max(share["seconds"] for share in shares),
        "processes": len(shares),
    }
    SUMMARY.write_text(json.dumps(summary, indent=2) + "\n")


@SCHEMA.parametrize()
@settings(
    max_examples=FUZZ_EXAMPLES,
    derandomize=True,
    database=None,
    deadline=None,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=list(HealthCheck),
)
def test_no_operation_answers_a_server_error(
    case: schemathesis.Case, fuzz_server: str, fuzz_auth: dict
) -> None:
    response = case.call_and_validate(
        base_url=fuzz_server, headers=fuzz_auth, checks=[not_a_server_error]
    )
    _operations.add(case.operation.label)
    _statuses[response.status_code] += 1
