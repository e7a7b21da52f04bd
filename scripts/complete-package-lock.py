#!/usr/bin/env python3
"""Give frontend/package-lock.json an entry for every platform build of rollup.

The npm registry reachable here lacks rollup's builds for other platforms (android, darwin,
win32, ...), so `npm install` leaves them out of the lock, and `npm ci` then refuses the lock
as out of sync with package.json. Entries naming each build's os/cpu/libc (what rollup
publishes) make the lock whole: `npm ci` skips them on this platform without fetching them,
and a machine of that platform fetches its own. Run after every `npm install`.
"""

import json
import sys
from pathlib import Path

LOCK = Path(__file__).resolve().parents[1] / "frontend" / "package-lock.json"


def platform_of(name: str) -> dict:
    """os/cpu/libc from a build's name, e.g. rollup-linux-arm64-musl, rollup-win32-x64-msvc."""
    parts = name.split("/")[-1].removeprefix("rollup-").split("-")
    os_name, cpu = parts[0], parts[1]
    entry: dict = {"cpu": [cpu], "os": [os_name]}
    if os_name == "linux":
        abi = parts[2] if len(parts) > 2 else "gnu"
        entry["libc"] = ["musl" if abi.startswith("musl") else "glibc"]
    return entry


def main() -> int:
    lock = json.loads(LOCK.read_text())
    packages = lock["packages"]
    added = 0
    for path, package in list(packages.items()):
        if not path.endswith("node_modules/rollup"):
            continue
        for name, version in package.get("optionalDependencies", {}).items():
            key = f"node_modules/{name}"
            if not name.startswith("@rollup/rollup-") or key in packages:
                continue
            packages[key] = {
                "version": version,
                **platform_of(name),
                "dev": package.get("dev", False),
                "license": "MIT",
                "optional": True,
            }
            added += 1
    lock["packages"] = dict(sorted(packages.items(), key=lambda kv: (kv[0] != "", kv[0])))
    LOCK.write_text(json.dumps(lock, indent=2) + "\n")
    print(f"{added} platform entries added to {LOCK.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
