"""Errors a run can meet on disk, importable without torch (node start-up refusals name them)."""


class CheckpointError(RuntimeError):
    """A checkpoint or policy file that cannot be used: unreadable, not ours, or mismatched."""


class CheckpointWriteError(OSError):
    """A file could not be written (full disk, read-only folder...); the previous one is intact."""

    def __str__(self) -> str:
        return self.strerror or super().__str__()  # 'cannot write <path>: <why>', no '[Errno N]'


class RunFolderError(ValueError):
    """The output folder cannot be used as asked (a start-up refusal, one line)."""
