"""Safe iteration over zip archives, read in place (never unpacked to disk).

A member whose path would escape an extraction target (``..`` components,
absolute paths, drive letters, backslash tricks) is never opened: it is
reported as rejected with the reason, and the rest of the archive is read.

A member is read whole into memory, so :meth:`Archive.read` refuses one whose
uncompressed size exceeds ``max_member_bytes`` or whose compression ratio exceeds
``max_ratio`` (a zip bomb) with an :class:`InputError`, before decompressing it;
the read itself never returns more than the size the member declares.
"""

from __future__ import annotations

import fnmatch
import posixpath
import zipfile
import zlib
from pathlib import Path

from .types import InputError, Rejected


def unsafe_reason(name: str) -> str | None:
    """Why ``name`` is unsafe as an archive member path, or ``None`` when it is safe."""
    n = name.replace("\\", "/")
    if n.startswith("/"):
        return "absolute path escapes the archive root"
    if len(n) > 1 and n[1] == ":":
        return "drive-letter path escapes the archive root"
    parts = n.split("/")
    if ".." in parts:
        return "path with '..' escapes the archive root"
    if "\x00" in n:
        return "NUL byte in member name"
    norm = posixpath.normpath(n)
    if norm.startswith("../") or norm == "..":
        return "path escapes the archive root"
    return None


class Archive:
    """A read-only view of one zip archive.

    ``names`` are the safe file members (directories dropped); ``unsafe`` holds a
    :class:`Rejected` entry for every hostile member.
    """

    def __init__(self, path: str | Path, max_member_bytes: int | None = None, max_ratio: float | None = None):
        self.path = Path(path)
        self.max_member_bytes, self.max_ratio = max_member_bytes, max_ratio
        if not self.path.exists():
            raise InputError(str(self.path), "no such archive (`dvc pull` restores the team's archives)")
        try:
            self._zip = zipfile.ZipFile(self.path)
        except (zipfile.BadZipFile, OSError) as e:
            raise InputError(str(self.path), f"cannot open archive: {e}") from None
        self.names: list[str] = []
        self.unsafe: list[Rejected] = []
        for info in self._zip.infolist():
            if info.is_dir():
                continue
            why = unsafe_reason(info.filename)
            if why:
                self.unsafe.append(Rejected(info.filename, why))
            else:
                self.names.append(info.filename)
        self._safe = set(self.names)

    def __enter__(self) -> "Archive":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._zip.close()

    def glob(self, pattern: str) -> list[str]:
        """Safe members matching a shell pattern (``*`` does not cross ``/``), sorted."""
        return sorted(n for n in self.names if matches(n, pattern))

    def read(self, name: str) -> bytes:
        """The bytes of a safe member; a corrupt member raises :class:`InputError`."""
        if name not in self._safe:
            raise InputError(name, "not a safe member of the archive")
        info = self._zip.getinfo(name)
        if self.max_member_bytes is not None and info.file_size > self.max_member_bytes:
            raise InputError(name, f"uncompressed size {_mb(info.file_size)} exceeds the limit of "
                                   f"{_mb(self.max_member_bytes)} (ingest.max_member_mb): not read")
        ratio = info.file_size / max(info.compress_size, 1)
        if self.max_ratio is not None and ratio > self.max_ratio:
            raise InputError(name, f"compression ratio {ratio:.0f}:1 exceeds the limit of {self.max_ratio:g}:1 "
                                   f"(ingest.max_compression_ratio; a zip bomb?): not read")
        try:
            with self._zip.open(info) as f:    # stops at the declared size, then checks the CRC
                return f.read()
        except (zipfile.BadZipFile, OSError, EOFError, ValueError, zlib.error) as e:
            raise InputError(name, f"corrupt archive member: {e}") from e

    def text(self, name: str, encoding: str = "utf-8") -> str:
        data = self.read(name)
        try:
            return data.decode(encoding)
        except UnicodeDecodeError as e:
            raise InputError(name, f"not {encoding} text: {e}") from e


def _mb(n: int) -> str:
    return f"{n / 2**20:,.1f} MB"


def matches(name: str, pattern: str) -> bool:
    """fnmatch where ``*`` stays within one path segment and ``**/`` spans any depth."""
    if "**/" in pattern:
        head, tail = pattern.split("**/", 1)
        if not name.startswith(head):
            return False
        rest = name[len(head):]
        parts = rest.split("/")
        return any(matches("/".join(parts[i:]), tail) for i in range(len(parts)))
    np_, pp = name.split("/"), pattern.split("/")
    return len(np_) == len(pp) and all(fnmatch.fnmatchcase(a, b) for a, b in zip(np_, pp))
