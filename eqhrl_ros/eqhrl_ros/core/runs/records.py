"""A run's folder: the per-episode record (episodes.csv) and the files a learner saves.

No ROS here. One learner writes one folder. The rules:

- A fresh run never replaces a folder that holds a run (an episodes.csv or a
  checkpoint) unless told to overwrite it; ``resume`` continues it.
- A folder that cannot be made or written is refused at start-up with one line.
- Temporary files of saves that were killed half-way are removed at start-up.
- On resume, rows of episodes the checkpoint has not finished are dropped, so the
  record has neither duplicates nor gaps.
- episodes.csv is appended with plain ``os.write``; a row that cannot be written
  (full disk) is kept and written with the next one, so no row is lost or torn.
"""

from __future__ import annotations

import csv
import io
import os
import tempfile
from pathlib import Path
from typing import Optional, Sequence

from ..data.errors import RunFolderError
from .provenance import note_provenance

# Saves write '.<name>.<random>.tmp' beside their target, then rename it (core/runs/checkpoint.py).
TEMPORARY_GLOB = '.*.pt.*.tmp'


def previous_replay_path(replay_path) -> Path:
    """Where a save keeps the previous replay file until its new checkpoint is in place
    (core/runs/checkpoint.py): a resume may need it, so it is not a temporary."""
    replay_path = Path(replay_path)
    return replay_path.with_name(f'.{replay_path.name}.previous')


# A run's MCAP record: record.mcap, then record-1.mcap, ... for each resume (eqhrl_ros/mcap_record.py).
RECORD_FILES = 'record*.mcap'
RUN_FILES = ('episodes.csv', 'checkpoint.pt', 'replay.pt', previous_replay_path('replay.pt').name, 'policy.pt')


def remove_stale_temporaries(folder) -> list[Path]:
    """Delete temporary files that saves killed half-way left in ``folder``; returns them."""
    removed = []
    for tmp in Path(folder).glob(TEMPORARY_GLOB):
        try:
            tmp.unlink()
            removed.append(tmp)
        except OSError:
            pass
    return removed


class RunFolder:
    """``output_dir`` checked and prepared for a fresh, resumed or overwriting run."""

    def __init__(self, path, resume: bool = False, overwrite: bool = False):
        self.path = Path(path)
        self.checkpoint = self.path / 'checkpoint.pt'
        self.replay = self.path / 'replay.pt'
        self.policy = self.path / 'policy.pt'
        self.episodes = self.path / 'episodes.csv'
        if resume and overwrite:  # before: resume won, unsaid
            raise RunFolderError(
                f"resume and overwrite both given: resume continues the run in '{self.path}', overwrite replaces it; "
                'give one'
            )
        if self.path.exists() and not self.path.is_dir():
            raise RunFolderError(f"output folder '{self.path}' is a file")
        if resume and not self.checkpoint.exists():  # before the folder is made: a refusal leaves none behind
            raise RunFolderError(f"nothing to resume: '{self.checkpoint}' does not exist")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            fd, probe = tempfile.mkstemp(dir=self.path, prefix='.write-test.')
            os.close(fd)
            os.unlink(probe)
        except OSError as error:
            raise RunFolderError(f"output folder '{self.path}' cannot be written: {error.strerror or error}") from error
        existing = [name for name in ('episodes.csv', 'checkpoint.pt') if (self.path / name).exists()]
        if existing and not (resume or overwrite):
            raise RunFolderError(
                f"output folder '{self.path}' holds a run ({', '.join(existing)}): resume it "
                '(resume:=true, eqhrl-train --resume) or replace it (overwrite:=true, --overwrite)'
            )
        self.removed_temporaries = remove_stale_temporaries(self.path)
        self.overwrite = overwrite
        self.provenance: Optional[Path] = None

    def begin(self, **about) -> None:
        """The start is accepted (the learner is built, its checkpoint or prior loaded): note what
        made it in provenance.yaml, with ``about`` (the env, mode and seed: eqhrl-report reads a
        single run's by them), and, with overwrite, remove the run it replaces. Until
        2026-12-05 both happened when the folder was opened, so a start refused later (a prior of
        another env, a learner that never got its spaces) left an entry for a start that never
        ran, and with overwrite had already removed the run it did not replace."""
        if self.overwrite:
            for name in RUN_FILES:
                (self.path / name).unlink(missing_ok=True)
            for record in self.path.glob(RECORD_FILES):  # the MCAP record (record: true), resumes included
                record.unlink(missing_ok=True)
        self.provenance = note_provenance(self.path, about)  # what made this start of the run


class EpisodeRecord:
    """episodes.csv: a header, then one row per episode, each written whole."""

    def __init__(self, path, fields: Sequence[str], keep_before: Optional[int] = None):
        """Open ``path`` for appending. ``keep_before``: resuming at that episode, so rows of
        later episodes (to be run again) are dropped first; None: a fresh record."""
        self.path = Path(path)
        self.fields = tuple(fields)
        # Episodes before the resume point whose rows the file lacks (torn by a kill mid-write, or
        # lost with the disk): said by gap_warning, since the record cannot be made whole again.
        self.missing: list[int] = []
        if keep_before is not None:
            self.missing = _truncate_to(self.path, keep_before, self.fields)
        else:
            _start_with_header(self.path, self.fields)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        self._pending = b''
        self.unwritten_rows = 0
        if os.fstat(self._fd).st_size == 0:  # the header could not be written yet (a full disk): with the first row
            self._pending = _encode(self.fields)

    def append(self, row: Sequence) -> Optional[OSError]:
        """Add a row; returns the OSError if it (or an earlier one) could not be written yet."""
        self._pending += _encode(row)
        self.unwritten_rows += 1
        return self.flush()

    def flush(self) -> Optional[OSError]:
        try:
            while self._pending:
                written = os.write(self._fd, self._pending)
                self._pending = self._pending[written:]
        except OSError as error:
            return error
        self.unwritten_rows = 0
        return None

    def close(self) -> Optional[OSError]:
        if self._fd < 0:
            return None
        error = self.flush()
        os.close(self._fd)
        self._fd = -1
        return error

    @property
    def closed(self) -> bool:
        return self._fd < 0

    @property
    def gap_warning(self) -> str:
        """One line for the log when the resumed record lacks rows ('' when it is whole)."""
        if not self.missing:
            return ''
        shown = ', '.join(map(str, self.missing[:10])) + (f' and {len(self.missing) - 10} more' if len(self.missing) > 10 else '')
        return (
            f'{self.path}: no whole row for episode(s) {shown} (a row torn by a kill during its write, or '
            'lost with the disk); they stay missing from the record, the run goes on'
        )


def _encode(row: Sequence) -> bytes:
    text = io.StringIO()
    csv.writer(text).writerow(row)
    return text.getvalue().encode()


def _start_with_header(path: Path, fields: Sequence[str]) -> None:
    """A fresh record: its header only, put in place whole (written aside, then renamed), so that
    a reader never finds the file empty or half a header (csv.DictReader on a file that was empty
    when it looked took the first row for the header). Where the header cannot be written, the
    old file is gone all the same and the header waits for the first row."""
    tmp = path.with_suffix('.csv.tmp')
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            header = _encode(fields)
            while header:
                header = header[os.write(fd, header) :]
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        path.unlink(missing_ok=True)


def _truncate_to(path: Path, episode: int, fields: Sequence[str]) -> list[int]:
    """Keep only whole rows of episodes < ``episode`` (a resumed learner redoes the others);
    returns those episodes that have no whole row."""
    if not path.exists():
        _start_with_header(path, fields)
        return list(range(episode))
    raw = path.read_bytes()
    rows = list(csv.reader(io.StringIO(raw.decode(errors='replace'), newline='')))
    if rows and not raw.endswith(b'\n') and len(rows) > 1:
        rows.pop()  # rows are appended whole, each with its line end: one without was torn mid-write
    if not rows:
        _start_with_header(path, fields)
        return list(range(episode))
    width = len(rows[0])
    body = [r for r in rows[1:] if len(r) == width and r[0].lstrip('-').isdigit() and int(r[0]) < episode]
    missing = sorted(set(range(episode)) - {int(r[0]) for r in body})
    header = rows[0]
    if tuple(header) != tuple(fields):
        # An older record (fewer columns): keep its rows, padded with empty new columns.
        body = [r + [''] * (len(fields) - len(r)) for r in body] if len(header) < len(fields) else body
        header = list(fields)
    tmp = path.with_suffix('.csv.tmp')
    with tmp.open('w', newline='') as f:
        csv.writer(f).writerows([header, *body])
    os.replace(tmp, path)
    return missing
