"""The row of a file in storage, created or brought up to date with the file as it is now."""

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import StoredFile
from backend.storage import LocalStorage, file_digest


def record_stored_file(
    session: Session, storage: LocalStorage, relative: str, media_type: str
) -> StoredFile:
    """Idempotent: a file written again (a stage or report rerun) updates its row."""
    size, sha256 = file_digest(storage.absolute(relative))
    stored = session.scalar(select(StoredFile).where(StoredFile.path == relative))
    if stored is None:
        stored = StoredFile(path=relative, size_bytes=size, sha256=sha256, media_type=media_type)
        session.add(stored)
        session.flush()
    else:
        stored.size_bytes, stored.sha256, stored.media_type = size, sha256, media_type
    return stored
