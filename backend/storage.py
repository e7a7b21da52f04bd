"""Local file storage: uploads are streamed to disk with their size and SHA-256.

Files are written under a temporary name and renamed into place only when complete, so
an interrupted upload never leaves a partial file under a real name.
"""

import hashlib
import os
import shutil
import uuid
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path


class UploadTooLarge(Exception):
    def __init__(self, limit: int) -> None:
        super().__init__(f"upload is larger than the limit of {limit} bytes")
        self.limit = limit


@dataclass(frozen=True)
class SavedFile:
    relative_path: str
    size_bytes: int
    sha256: str


def file_digest(path: Path) -> tuple[int, str]:
    """Size in bytes and SHA-256 hex digest of a file."""
    digest = hashlib.sha256()
    size = 0
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
            size += len(chunk)
    return size, digest.hexdigest()


class LocalStorage:
    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    def absolute(self, relative_path: str) -> Path:
        path = (self.root / relative_path).resolve()
        if not path.is_relative_to(self.root.resolve()):
            raise ValueError(f"path {relative_path!r} leaves the storage root")
        return path

    def new_relative_path(self, folder: str, suffix: str) -> str:
        return f"{folder}/{uuid.uuid4().hex}{suffix}"

    async def save_stream(
        self, chunks: AsyncIterator[bytes], folder: str, suffix: str, max_bytes: int
    ) -> SavedFile:
        """Stream `chunks` to a new file; raise UploadTooLarge past `max_bytes`."""
        relative = self.new_relative_path(folder, suffix)
        target = self.absolute(relative)
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.with_name(f".{target.name}.part")
        digest = hashlib.sha256()
        size = 0
        try:
            with open(partial, "wb") as out:
                async for chunk in chunks:
                    size += len(chunk)
                    if size > max_bytes:
                        raise UploadTooLarge(max_bytes)
                    digest.update(chunk)
                    out.write(chunk)
            os.replace(partial, target)
        finally:
            partial.unlink(missing_ok=True)
        return SavedFile(relative, size, digest.hexdigest())

    def import_file(self, source: Path, folder: str, suffix: str) -> SavedFile:
        """Copy a finished file (e.g. a job output) into storage."""
        relative = self.new_relative_path(folder, suffix)
        target = self.absolute(relative)
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.with_name(f".{target.name}.part")
        digest = hashlib.sha256()
        size = 0
        try:
            with open(source, "rb") as src, open(partial, "wb") as out:
                while chunk := src.read(1 << 20):
                    digest.update(chunk)
                    out.write(chunk)
                    size += len(chunk)
            os.replace(partial, target)
        finally:
            partial.unlink(missing_ok=True)
        return SavedFile(relative, size, digest.hexdigest())

    def adopt_file(self, source: Path, folder: str, suffix: str) -> SavedFile:
        """Move a finished file (e.g. a completed resumable upload) into storage."""
        size, sha256 = file_digest(source)
        relative = self.new_relative_path(folder, suffix)
        target = self.absolute(relative)
        target.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.replace(source, target)
        except OSError:  # another file system: copy, then rename into place
            saved = self.import_file(source, folder, suffix)
            Path(source).unlink()
            return saved
        return SavedFile(relative, size, sha256)

    def delete(self, relative_path: str) -> None:
        self.absolute(relative_path).unlink(missing_ok=True)

    def delete_tree(self, relative_folder: str) -> None:
        shutil.rmtree(self.absolute(relative_folder), ignore_errors=True)
