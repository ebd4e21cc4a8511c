"""Atomic file writes, to a local path or to a filesystem URI.

Locally: write to a temporary file beside the target, then rename it over the target. ``os.replace`` within one
directory is atomic on POSIX and Windows, so a reader (or a resumed sweep) sees either the old file, no file, or the
complete new file, never a partial one, even if the writer is killed.

A *location* is a local path (``str`` or :class:`~pathlib.Path`) or a URI that :meth:`pyarrow.fs.FileSystem.from_uri`
understands (``file:///data/run``, ``s3://bucket/prefix``, ``gs://…``, ``hdfs://…``) or, failing that, that
`fsspec <https://filesystem-spec.readthedocs.io>`_ does (``memory://``, ``abfs://`` with adlfs installed, …). Workers
of a distributed run write their results straight to such a URI, so no node needs a shared disk. On a remote
filesystem the object is written under a temporary name beside the target and then moved over it; on object stores
(S3, GCS) the move is a server-side copy, which creates the target complete or not at all. Credentials come from each
process's own environment (e.g. ``AWS_*`` variables or an instance profile), never from scaletwin.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

Location = str | Path


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary local path to write to; on success it replaces ``path``, on error it is deleted.

    The temporary name starts with ``.`` and ends with ``.tmp`` so that globbing ``*.parquet`` never sees it.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.parent / _temporary_name(target.name)  # created by the writer
    try:
        yield tmp
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


def is_uri(location: Location) -> bool:
    """Whether ``location`` is a URI (``scheme://…``) rather than a local path."""
    return not isinstance(location, Path) and "://" in location


def resolve(location: Location) -> tuple[Any, str]:
    """``(filesystem, path)`` of a location: a :class:`pyarrow.fs.FileSystem` and the path within it.

    A local path (relative ones are made absolute) and a ``file://`` URI give a :class:`pyarrow.fs.LocalFileSystem`;
    other URIs go to :meth:`pyarrow.fs.FileSystem.from_uri`, then to fsspec (wrapped in
    :class:`pyarrow.fs.PyFileSystem`).

    Raises:
        ValueError: a URI that neither pyarrow nor fsspec knows (the message names it).
    """
    import pyarrow as pa
    import pyarrow.fs as pafs

    if not is_uri(location):
        return pafs.LocalFileSystem(), Path(location).absolute().as_posix()
    text = str(location)
    try:
        return pafs.FileSystem.from_uri(text)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as arrow_error:
        try:
            import fsspec.core
        except ImportError:  # pragma: no cover - fsspec comes with torch
            raise ValueError(f"unsupported filesystem URI {text!r}: {arrow_error}") from arrow_error
        try:
            fs, path = fsspec.core.url_to_fs(text)
        except (ImportError, ValueError) as exc:
            raise ValueError(f"unsupported filesystem URI {text!r}: {arrow_error}; fsspec: {exc}") from exc
        return pafs.PyFileSystem(pafs.FSSpecHandler(fs)), path


def join(location: Location, name: str) -> Location:
    """The location of ``name`` inside the folder ``location`` (a :class:`Path` for a path, a URI for a URI)."""
    if is_uri(location):
        return f"{str(location).rstrip('/')}/{name}"
    return Path(location) / name


def is_local(location: Location) -> bool:
    """Whether ``location`` lies on this machine's filesystem (a path or a ``file://`` URI)."""
    import pyarrow.fs as pafs

    return isinstance(resolve(location)[0], pafs.LocalFileSystem)


def make_dirs(location: Location) -> None:
    """Create the folder ``location`` and its parents (object stores have no folders: nothing to do there)."""
    fs, path = resolve(location)
    if _local_path(fs, path) is not None:
        Path(path).mkdir(parents=True, exist_ok=True)  # here a failure is a real error: let it raise
        return
    with contextlib.suppress(OSError, NotImplementedError):  # a prefix in an object store needs no marker;
        fs.create_dir(path, recursive=True)  # a missing bucket or denied access fails at the first write


def exists(location: Location) -> bool:
    """Whether a file (or folder) exists at ``location``."""
    import pyarrow.fs as pafs

    fs, path = resolve(location)
    return fs.get_file_info(path).type != pafs.FileType.NotFound


def list_files(location: Location, prefix: str = "", suffix: str = "") -> list[str]:
    """Names (not paths) of the files directly inside the folder ``location`` that start with ``prefix`` and end
    with ``suffix``, sorted; an absent folder has none. Temporary files of :func:`atomic_output` start with ``.``
    and end with ``.tmp``, so they never match a prefix other than ``.``."""
    import pyarrow.fs as pafs

    fs, path = resolve(location)
    infos = fs.get_file_info(pafs.FileSelector(path, allow_not_found=True, recursive=False))
    names = (info.base_name for info in infos if info.type == pafs.FileType.File)
    return sorted(n for n in names if n.startswith(prefix) and n.endswith(suffix))


def read_bytes(location: Location) -> bytes:
    """The content of the file at ``location``.

    Raises:
        FileNotFoundError: there is no such file.
    """
    fs, path = resolve(location)
    with fs.open_input_stream(path) as f:
        return f.read()


@contextlib.contextmanager
def atomic_output(location: Location) -> Iterator[IO[bytes]]:
    """Yield a binary stream to write the file at ``location`` into; the file appears complete on success and is
    left as it was on error (a local path or ``file://`` URI: temporary file + rename; another filesystem:
    temporary object + move)."""
    fs, path = resolve(location)
    local = _local_path(fs, path)
    if local is not None:
        with atomic_path(local) as tmp, open(tmp, "wb") as f:
            yield f
        return
    parent, _, name = path.rpartition("/")
    tmp = f"{parent}/{_temporary_name(name)}" if parent else _temporary_name(name)
    moved = False
    try:
        with fs.open_output_stream(tmp) as stream:
            yield stream
        fs.move(tmp, path)
        moved = True
    finally:
        if not moved:
            with contextlib.suppress(OSError, FileNotFoundError):
                fs.delete_file(tmp)


def write_bytes_atomic(location: Location, data: bytes) -> Location:
    """Write ``data`` to ``location`` atomically; returns the location (a :class:`Path` for a path)."""
    with atomic_output(location) as f:
        f.write(data)
    return location if is_uri(location) else Path(location)


def write_text_atomic(location: Location, text: str) -> Location:
    """Write ``text`` (UTF-8) to ``location`` atomically; returns the location (a :class:`Path` for a path)."""
    return write_bytes_atomic(location, text.encode("utf-8"))


def _temporary_name(name: str) -> str:
    return f".{name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"


def _local_path(fs: Any, path: str) -> str | None:
    import pyarrow.fs as pafs

    return path if isinstance(fs, pafs.LocalFileSystem) else None
