"""eqhrl-report: a results table (like the paper's Tables 2-3) and figures (like Figs. 4-9).

    eqhrl-report runs/pendulum_paper --output docs/results/pendulum
    eqhrl-report runs/a runs/b --output report --threshold -200
    eqhrl-report runs/sac_seed1 runs/eqsac_seed1 --output report   # runs of eqhrl-train, ros2 launch

Reads <folder>/episodes.csv written by eqhrl-experiment (columns: algorithm, seed,
episode, return, length, advice_asked, advice_given, success) from one or more
folders, or a single run's episodes.csv (eqhrl-train, the learner node; its algorithm, seed
and env from the run's provenance.yaml, where the learner notes them), and writes table.md,
returns.png, advice.png, success.png and advice_heatmap.png into --output; where the folders
hold an eval.csv (the advice-free evaluation of eqhrl-experiment), also eval_returns.png.

Per algorithm, mean ± std over seeds of: total advice given (and asked), final
return (mean of the last 10% of episodes), success rate (last 10% and all
episodes), and the episodes needed to reach a return threshold (first episode at
which the Savitzky-Golay smoothed return reaches it; runs that never do are counted
apart).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..reports.run_report import (
    env_of,
    eval_figure,
    figures,
    format_table,
    read_eval,
    read_runs,
    return_threshold,
    summarize,
)
from .arguments import add_report_output, report_in_the_way


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog='eqhrl-report',
        description=__doc__.split('\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__,
    )
    parser.add_argument('folders', nargs='+', help="eqhrl-experiment output folders or single runs' folders")
    add_report_output(parser, 'folder for table.md and the PNGs')
    args = parser.parse_args(argv)
    output = Path(args.output)
    if report_in_the_way('eqhrl-report', args):
        return 2
    try:
        runs = read_runs(args.folders)
    except (FileNotFoundError, ValueError) as error:
        print(f'eqhrl-report: {error}', file=sys.stderr)
        return 1
    if not runs:
        print('eqhrl-report: no finished runs in the given folders', file=sys.stderr)
        return 1
    env_id = env_of(args.folders)
    threshold = return_threshold(
        env_id, args.threshold, say=lambda line: print(f'eqhrl-report: {line}', file=sys.stderr)
    )
    output.mkdir(parents=True, exist_ok=True)
    text = format_table(summarize(runs, threshold), threshold)
    (output / 'table.md').write_text(text + '\n')
    print(text)
    made = figures(runs, output, env_id)
    evals = read_eval(args.folders)
    if evals:
        made.append(eval_figure(evals, output, env_id))
    for path in made:
        print(f'wrote {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
