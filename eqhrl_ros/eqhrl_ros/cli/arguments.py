"""Command-line values checked by meaning as argparse reads them: a bad one is a usage line and
exit code 2, not a traceback from a worker process, nor a run of -5 episodes that 'finished'."""

from __future__ import annotations

import argparse
from typing import Callable

from ..core.algorithm.config import check_value


def config_value(name: str, cast: Callable = int) -> Callable[[str], object]:
    """An argparse type: the text as ``cast``, in the range LearnerConfig gives its field ``name``
    (the learner's own check, so the command and the learner never disagree)."""

    def parse(text: str):
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'{text!r} is not {"an integer" if cast is int else "a number"}') from None
        try:
            return check_value(name, value)
        except (ValueError, OverflowError) as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    parse.__name__ = name  # argparse names the type in its message
    return parse


def at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type: an integer of at least ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'{text!r} is not an integer') from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f'{value} is below {minimum}')
        return value

    parse.__name__ = f'integer >= {minimum}'
    return parse
