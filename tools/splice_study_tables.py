"""Put eqhrl-study-report's tables into docs/results.md, between the page's markers.

    .venv/bin/python tools/splice_study_tables.py docs/results/study_pendulum_decisive/table.md

Each marker pair <!-- NAME --> ... <!-- /NAME --> on the page takes the body of the report's
section whose heading starts with SECTIONS[NAME] (for a second study on the same page, give
--prefix: <!-- PREFIX_NAME -->). The page's prose is not touched: read it again after a splice.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

SECTIONS = {
    'TESTS': 'Pre-stated tests',
    'ARMS': 'Arms',
    'FRONTIER': 'The effort frontier',
    'TIMING': 'When the arms asked',
    'PERSON': 'What the person spent',
    'PLACEMENT': 'Where the matched arms asked',
    'DIFFS': 'Same-seed differences',
}


def sections(report: str) -> dict:
    """{heading: body} of a report's '## ' sections."""
    found = {}
    for block in re.split(r'^## ', report, flags=re.M)[1:]:
        heading, _, body = block.partition('\n')
        found[heading.strip()] = body.strip()
    return found


def splice(page: str, report: str, prefix: str = '') -> tuple[str, list]:
    found = sections(report)
    done = []
    for name, heading in SECTIONS.items():
        marker = f'{prefix}_{name}' if prefix else name
        start, end = f'<!-- {marker} -->', f'<!-- /{marker} -->'
        if start not in page:
            continue
        body = next((b for h, b in found.items() if h.startswith(heading)), None)
        if body is None:
            raise ValueError(f'the report has no section "{heading}..." for the marker {marker}')
        head, _, rest = page.partition(start)
        _, _, tail = rest.partition(end)
        page = f'{head}{start}\n{body}\n{end}{tail}'
        done.append(marker)
    return page, done


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('report', help="eqhrl-study-report's table.md")
    parser.add_argument('--page', default='docs/results.md')
    parser.add_argument('--prefix', default='', help='markers <!-- PREFIX_NAME --> (a second study on the page)')
    args = parser.parse_args(argv)
    page = Path(args.page)
    try:
        text, done = splice(page.read_text(), Path(args.report).read_text(), args.prefix)
    except (OSError, ValueError) as error:
        print(f'splice_study_tables: {error}', file=sys.stderr)
        return 2
    page.write_text(text)
    print(f'spliced {", ".join(done) or "nothing"} into {page}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
