#!/usr/bin/env bash
# Run a command (the test suite) with a real PostgreSQL and a real Redis.
#
# Uses SLIDEWATCH_TEST_DATABASE_URL / SLIDEWATCH_TEST_REDIS_URL when set, else the servers
# on the standard local ports. Where none answers, installs them from Debian's packages
# and starts throwaway instances in a temporary directory, stopped again on exit.
set -euo pipefail

here=$(cd "$(dirname "$0")/.." && pwd)
python=${PYTHON:-$here/.venv/bin/python}
export SLIDEWATCH_TEST_DATABASE_URL=${SLIDEWATCH_TEST_DATABASE_URL:-postgresql+psycopg://postgres@127.0.0.1:5432/postgres}
export SLIDEWATCH_TEST_REDIS_URL=${SLIDEWATCH_TEST_REDIS_URL:-redis://127.0.0.1:6379/0}
throwaway=""

postgres_answers() {
  "$python" - "$SLIDEWATCH_TEST_DATABASE_URL" <<'PY' >/dev/null 2>&1
import sys, sqlalchemy
engine = sqlalchemy.create_engine(sys.argv[1], connect_args={"connect_timeout": 3})
with engine.connect() as c:
    c.exec_driver_sql("SELECT 1")
PY
}

redis_answers() {
  "$python" - "$SLIDEWATCH_TEST_REDIS_URL" <<'PY' >/dev/null 2>&1
import sys, redis
redis.Redis.from_url(sys.argv[1], socket_connect_timeout=3).ping()
PY
}

cleanup() {
  if [ -n "$throwaway" ]; then
    [ -f "$throwaway/pg/postmaster.pid" ] && runuser -u postgres -- "$pg_bin/pg_ctl" -D "$throwaway/pg" -m fast stop >/dev/null 2>&1 || true
    [ -f "$throwaway/redis.pid" ] && kill "$(cat "$throwaway/redis.pid")" 2>/dev/null || true
    rm -rf "$throwaway"
  fi
}
trap cleanup EXIT

if ! postgres_answers; then
  echo "no PostgreSQL answers at $SLIDEWATCH_TEST_DATABASE_URL: starting a throwaway one"
  ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || "$here/scripts/install-system-packages.sh" postgresql
  pg_bin=$(dirname "$(ls /usr/lib/postgresql/*/bin/initdb | sort -V | tail -n 1)")
  throwaway=${throwaway:-$(mktemp -d /tmp/slidewatch-services.XXXXXX)}
  chmod 755 "$throwaway"
  install -d -o postgres -g postgres "$throwaway/pg"
  runuser -u postgres -- "$pg_bin/initdb" -D "$throwaway/pg" -U postgres -A trust >/dev/null
  runuser -u postgres -- "$pg_bin/pg_ctl" -D "$throwaway/pg" -w -l "$throwaway/pg/log" \
    -o "-p 55432 -k $throwaway/pg -c listen_addresses=127.0.0.1" start >/dev/null
  export SLIDEWATCH_TEST_DATABASE_URL=postgresql+psycopg://postgres@127.0.0.1:55432/postgres
  postgres_answers
fi

if ! redis_answers; then
  echo "no Redis answers at $SLIDEWATCH_TEST_REDIS_URL: starting a throwaway one"
  command -v redis-server >/dev/null || "$here/scripts/install-system-packages.sh" redis-server
  throwaway=${throwaway:-$(mktemp -d /tmp/slidewatch-services.XXXXXX)}
  redis-server --port 56379 --bind 127.0.0.1 --save "" --appendonly no --daemonize yes \
    --pidfile "$throwaway/redis.pid" --dir "$throwaway" --logfile "$throwaway/redis.log"
  export SLIDEWATCH_TEST_REDIS_URL=redis://127.0.0.1:56379/0
  for _ in $(seq 50); do redis_answers && break; sleep 0.1; done
  redis_answers
fi

echo "tests use PostgreSQL $SLIDEWATCH_TEST_DATABASE_URL and Redis $SLIDEWATCH_TEST_REDIS_URL"
"$@"
