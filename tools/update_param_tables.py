"""Regenerate the parameter tables of eqhrl_ros/README.md from the node declarations.

    .venv/bin/python tools/update_param_tables.py

tests/test_docs.py fails when a declared parameter is missing from the README.
"""

from pathlib import Path

from eqhrl_ros.nodes.double_integrator_env_node import PARAMETERS as DOUBLE_INTEGRATOR_PARAMETERS
from eqhrl_ros.nodes.params import (
    EXPERT_PARAMS,
    GYM_ENV_PARAMS,
    KEYBOARD_PARAMS,
    LEARNER_CONFIG_PARAMS,
    LEARNER_NODE_PARAMS,
    TELEOP_EXPERT_PARAMS,
    Param,
)

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
    tables = '\n\n'.join(
        [
            table('gym_env', GYM_ENV_PARAMS),
            table('expert', EXPERT_PARAMS),
            table('learner: algorithm (core.LearnerConfig)', LEARNER_CONFIG_PARAMS),
            table('learner: node', LEARNER_NODE_PARAMS),
            table('teleop_expert', TELEOP_EXPERT_PARAMS),
            table('keyboard_teleop', KEYBOARD_PARAMS),
            table(
                'double_integrator_env (the example; its own PARAMETERS)',
                [Param(n, d, text, r) for n, d, text, r in DOUBLE_INTEGRATOR_PARAMETERS],
            ),
        ]
    )
    README.write_text(text[:start] + tables + '\n\n' + text[end:])


if __name__ == '__main__':
    main()
