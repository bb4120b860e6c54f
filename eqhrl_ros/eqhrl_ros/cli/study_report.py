"""eqhrl-study-report: the tables and figures of a study made by eqhrl-study.

    eqhrl-study-report runs/study_pendulum --output docs/results/study_pendulum

Everything is measured on the advice-free evaluation (eval.csv: the deterministic policy
alone from fixed start states every few episodes), never on training returns, which mix
the learner's actions with the expert's inside the budget. Per run:

- final: the mean evaluation return after the last episode;
- AUC: the mean evaluation return over all evaluations (the area under the evaluation
  curve divided by its length): how good the policy was along the way;
- episodes to threshold: the first evaluation whose mean reaches the env's threshold
  (report.THRESHOLDS; runs that never do are counted apart);
- requests: the advice the learner asked for (a person's effort), and advice given.

Per arm, the interquartile mean (IQM) over seeds with a 95 % bootstrap interval. Between
arms, the same-seed differences (the runner pairs seeds) with a 95 % bootstrap interval and
how many seeds the first arm won. Each advising arm is compared with plain SAC of the same
settings (the first SAC arm whose learner settings are the same, leaving out those SAC never
reads, such as the budget), and with the random-request arm matched to it, where there is
one. Where the plan has random arms at fixed rates (at least two), every other advising arm is
placed on their effort frontier: its gain over SAC minus chance's at the same request count.
Writes table.md, eval_<group>.png, profile.png, effort.png, frontier.png and gates.png into --output,
and copies the gathered CSVs beside them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..reports.study_report import write_report
from .arguments import add_report_output, report_in_the_way


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog='eqhrl-study-report',
        description=__doc__.split('\n')[0],
        epilog=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument('folder', help='the output folder of eqhrl-study')
    add_report_output(parser, 'where the tables and figures go')
    args = parser.parse_args(argv)
    folder, output = Path(args.folder), Path(args.output)
    if report_in_the_way('eqhrl-study-report', args):
        return 2
    for name in ('arms.csv', 'episodes.csv', 'eval.csv', 'plan.yaml'):
        if not (folder / name).exists():
            print(f'eqhrl-study-report: {folder / name} is missing (run eqhrl-study first)', file=sys.stderr)
            return 2
    try:
        write_report(folder, output, args.threshold)
    except ValueError as error:  # a table it cannot read (study_scores.read_csv names the row)
        print(f'eqhrl-study-report: {error}', file=sys.stderr)
        return 2
    print(f'wrote {output / "table.md"} and figures')
    return 0


if __name__ == '__main__':
    sys.exit(main())
