"""Safe iteration over zip archives, read in place (never unpacked to disk).

A member whose path would escape an extraction target (``..`` components,
absolute paths, drive letters, backslash tricks) is never opened: it is
reported as rejected with the reason, and the rest of the archive is read.
"""

from __future__ import annotations

import fnmatch
import posixpath
import zipfile
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

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            self._zip = zipfile.ZipFile(self.path)
        except (zipfile.BadZipFile, OSError) as e:
            raise InputError(str(path), f"cannot open archive: {e}") from e
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
        return sorted(n for n in self.names if _match(n, pattern))

    def read(self, name: str) -> bytes:
        """The bytes of a safe member; a corrupt member raises :class:`InputError`."""
        if name not in self._safe:
            raise InputError(name, "not a safe member of the archive")
        try:
            return self._zip.read(name)
        except (zipfile.BadZipFile, OSError, EOFError, ValueError) as e:
            raise InputError(name, f"corrupt archive member: {e}") from e

    def text(self, name: str, encoding: str = "utf-8") -> str:
        data = self.read(name)
        try:
            return data.decode(encoding)
        except UnicodeDecodeError as e:
            raise InputError(name, f"not {encoding} text: {e}") from e


def _match(name: str, pattern: str) -> bool:
    """fnmatch where ``*`` stays within one path segment and ``**/`` spans any depth."""
    if "**/" in pattern:
        head, tail = pattern.split("**/", 1)
        if not name.startswith(head):
            return False
        rest = name[len(head):]
        parts = rest.split("/")
        return any(_match("/".join(parts[i:]), tail) for i in range(len(parts)))
    np_, pp = name.split("/"), pattern.split("/")
    return len(np_) == len(pp) and all(fnmatch.fnmatchcase(a, b) for a, b in zip(np_, pp))
