"""Command-line values checked by meaning as argparse reads them: a bad one is a usage line and
exit code 2, not a traceback from a worker process, nor a run of -5 episodes that 'finished'."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
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


def add_report_output(parser: argparse.ArgumentParser, output_help: str) -> None:
    """--output, --overwrite and --threshold: the same three for eqhrl-report and eqhrl-study-report."""
    parser.add_argument('--output', required=True, help=output_help)
    parser.add_argument(
        '--overwrite', action='store_true', help='replace a table.md already in --output (e.g. committed results)'
    )
    parser.add_argument(
        '--threshold',
        type=float,
        help="return threshold (default: the env's: THRESHOLDS, else gymnasium's reward_threshold, else 0, said)",
    )


def report_in_the_way(prog: str, args: argparse.Namespace) -> bool:
    """True, said on stderr, when --output holds a report already and --overwrite is not given:
    committed results are never replaced by a mistyped folder."""
    output = Path(args.output)
    if (output / 'table.md').exists() and not args.overwrite:
        print(f'{prog}: {output} holds a report already (table.md); give --overwrite to replace it', file=sys.stderr)
        return True
    return False
