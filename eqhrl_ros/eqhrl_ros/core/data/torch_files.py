"""torch's zip files, written atomically and read safely (checkpoints, replay memories, exported policies).

Files are read with ``torch.load(weights_only=True)``: only tensors and plain Python containers are
ever unpickled, so a malicious file cannot run code. Before that, the zip's directory is checked:
torch never compresses, so a compressed entry (a deflate bomb) is refused, and a file larger than
the caller says it can need is refused before it is read.

Writes: the whole file is serialized in memory, written to a temporary file beside the target with
plain ``os.write`` (so a full disk or a read-only folder is an ``OSError`` that names itself),
flushed to disk and renamed into place. A failed write leaves the previous file as it was.
"""

from __future__ import annotations

import io
import os
import pickle
import tempfile
import zipfile
from pathlib import Path

import torch

from .errors import CheckpointError, CheckpointWriteError

FORMAT_VERSION = 1


def write_file(data: bytes | memoryview, tmp: str) -> None:
    fd = os.open(tmp, os.O_WRONLY | os.O_TRUNC)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        os.fsync(fd)
    finally:
        os.close(fd)


def write_temporary(obj: dict, path: Path) -> str:
    """Serialize ``obj`` and write it to a temporary file beside ``path``; returns its name."""
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.tmp')
    except OSError as error:
        raise CheckpointWriteError(error.errno, f'cannot write {path}: {error.strerror}') from error
    os.close(fd)
    try:
        write_file(buffer.getbuffer(), tmp)
    except OSError as error:
        Path(tmp).unlink(missing_ok=True)
        raise CheckpointWriteError(error.errno, f'cannot write {path}: {error.strerror}') from error
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return tmp


def replace_file(tmp: str, path: Path) -> None:
    try:
        os.replace(tmp, path)
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)  # the rename itself reaches the disk
        finally:
            os.close(dir_fd)
    except OSError as error:
        Path(tmp).unlink(missing_ok=True)
        raise CheckpointWriteError(error.errno, f'cannot write {path}: {error.strerror}') from error


def atomic_save(obj: dict, path: Path) -> None:
    path = Path(path)
    replace_file(write_temporary(obj, path), path)


def check_zip(path: Path, expected_format: str, max_bytes: int | None) -> None:
    """Refuse, before unpickling, what torch.save never writes or what is larger than needed."""
    size = path.stat().st_size
    if max_bytes is not None and size > max_bytes:
        raise CheckpointError(f"{path}: {size:,} bytes, more than the {max_bytes:,} that this learner's sizes can need")
    try:
        with zipfile.ZipFile(path) as archive:
            entries = archive.infolist()
    except (zipfile.BadZipFile, OSError, ValueError) as error:
        raise CheckpointError(f'{path}: not a readable {expected_format} file ({error})') from error
    for entry in entries:
        if entry.compress_type != zipfile.ZIP_STORED:
            raise CheckpointError(
                f'{path}: entry {entry.filename!r} is compressed; torch.save never '
                'compresses, so the file is refused unread'
            )
        if entry.file_size > size:
            raise CheckpointError(
                f'{path}: entry {entry.filename!r} claims {entry.file_size:,} bytes in a file of {size:,}'
            )


def not_a_file(path: Path) -> str:
    """Why ``path`` cannot be read as a file ('' when it can): missing, or a folder (a run's folder
    where its policy.pt or checkpoint.pt was meant)."""
    if path.is_dir():
        return f'{path}: a folder, not a file'
    return '' if path.is_file() else f'{path}: no such file'


def safe_load(path: Path, expected_format: str, max_bytes: int | None = None) -> dict:
    path = Path(path)
    if not_a_file(path):
        raise CheckpointError(not_a_file(path))
    check_zip(path, expected_format, max_bytes)
    try:
        obj = torch.load(path, map_location='cpu', weights_only=True)
    except (
        pickle.UnpicklingError,
        RuntimeError,
        EOFError,
        zipfile.BadZipFile,
        ValueError,
        AttributeError,
        TypeError,
        OSError,
    ) as error:
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise CheckpointError(f'{path}: not a readable {expected_format} file ({first_line})') from error
    if not isinstance(obj, dict) or obj.get('format') != expected_format:
        found = obj.get('format') if isinstance(obj, dict) else type(obj).__name__
        raise CheckpointError(f'{path}: expected an {expected_format} file, found {found!r}')
    if obj.get('version') != FORMAT_VERSION:
        raise CheckpointError(f'{path}: format version {obj.get("version")!r}, this code reads {FORMAT_VERSION}')
    return obj
