"""Temporary files that a killed stage left in its job's folder, removed before it runs again.

The library writes every output through a temporary beside it and removes its temporary
folders when a stage ends, by returning or raising; a stage killed with its process
(SIGKILL, the kernel's OOM killer) leaves them behind. Once the runner has claimed a stage,
no other attempt of that job runs (its stages run one at a time, and a claim that went
stale is dead), so whatever temporary is in the job's folder then belongs to an attempt
that died.

The names are those the library's writers give their temporaries (a test checks them
against the writers):

- `atomic_path` (worker/pipeline/atomic.py): `.{name}.{random}.part{suffix}`, files;
- `tempfile.TemporaryDirectory(dir=...)`, `mkdtemp` and `mkstemp` with the default
  prefix: `tmp{random}` (the CNN detection stage's probability raster);
- the DSM export's folder (worker/pipeline/dsm_export.py): `.dsm-{random}`.
"""

import logging
import os
import re
import shutil
from pathlib import Path

log = logging.getLogger(__name__)

_RANDOM = r"[a-z0-9_]{8}"  # tempfile's random part: 8 of [a-z0-9_]
LEFTOVER_NAMES = re.compile(
    rf"^(?:\..+\.{_RANDOM}\.part(?:\.[^./]+)?|tmp{_RANDOM}|\.dsm-{_RANDOM})$"
)


def is_leftover(name: str) -> bool:
    """Whether a file or folder named `name` is a temporary of a stage's writers."""
    return LEFTOVER_NAMES.match(name) is not None


def remove_leftovers(folder: Path | None) -> list[Path]:
    """Remove the stage temporaries anywhere under `folder`; the paths removed.

    Symbolic links (a reconstruction's links to its uploaded files) are not followed.
    """
    if folder is None or not folder.is_dir():
        return []
    removed = []
    for parent, folders, files in os.walk(folder):
        for name in [*folders]:
            if is_leftover(name):
                path = Path(parent) / name
                shutil.rmtree(path, ignore_errors=True)
                folders.remove(name)  # not walked into: it is gone
                removed.append(path)
        for name in files:
            if is_leftover(name):
                path = Path(parent) / name
                path.unlink(missing_ok=True)
                removed.append(path)
    if removed:
        log.warning(
            "removed %d temporaries of a killed attempt under %s: %s",
            len(removed),
            folder,
            ", ".join(str(p.relative_to(folder)) for p in removed[:10]),
        )
    return removed


def job_folder(inputs: dict[str, object]) -> Path | None:
    """The folder a job's stages write in, as every job kind names it in its inputs."""
    folder = inputs.get("work_dir") or inputs.get("out_dir")
    return Path(str(folder)) if folder else None
