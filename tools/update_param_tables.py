"""Regenerate the parameter tables of eqhrl_ros/README.md from the node declarations.

    .venv/bin/python tools/update_param_tables.py

tests/test_docs.py fails when a declared parameter is missing from the README.
"""

from pathlib import Path

from eqhrl_ros.cli.node_programs import NODES, node_tables

README = Path(__file__).resolve().parents[1] / 'eqhrl_ros' / 'README.md'


def number(value) -> str:
    return '2³¹−1' if value == 2**31 - 1 else f'{value:g}'


def table(title, params) -> str:
    lines = [
        f'#### {title}',
        '',
        '| parameter | default | range / choices | run-time | description |',
        '|---|---|---|---|---|',
    ]
    for p in params:
        allowed = (
            ', '.join(p.choices) if p.choices else (f'{number(p.range[0])} … {number(p.range[1])}' if p.range else '')
        )
        default = 'unset' if p.default is None else f'`{p.default}`' if p.default != '' else '`""`'
        lines.append(f'| `{p.name}` | {default} | {allowed} | {"yes" if p.dynamic else ""} | {p.description} |')
    return '\n'.join(lines)


def main():
    text = README.read_text()
    start, end = text.index('#### gym_env'), text.index('## Benchmarks')
    # One table per parameter table of each node, in the order of cli/node_programs.NODES; a table that
    # several nodes declare (the algorithm's) once.
    unique = {title: params for name in NODES for title, params in node_tables(name)}
    tables = '\n\n'.join(table(title, params) for title, params in unique.items())
    README.write_text(text[:start] + tables + '\n\n' + text[end:])


if __name__ == '__main__':
    main()
