"""core/ is a library with no circles: no module reaches itself through its imports, and none
imports ROS (the nodes are thin adapters over it)."""

import ast
from pathlib import Path

CORE = Path(__file__).resolve().parents[2] / 'eqhrl_ros' / 'core'


def imports_of(path: Path) -> set:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1:  # from .x import y, or from . import x
                found |= {node.module.split('.')[0]} if node.module else {a.name for a in node.names}
            elif node.level == 0 and node.module:
                found.add(node.module)
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
    return found


def test_core_has_no_import_circles_and_no_ros():
    modules = {p.stem: imports_of(p) for p in CORE.glob('*.py') if p.stem != '__init__'}
    graph = {m: {d for d in deps if d in modules} for m, deps in modules.items()}
    ros = {
        m: sorted(d for d in deps if d.split('.')[0] in ('rclpy', 'std_msgs', 'eqhrl_interfaces'))
        for m, deps in modules.items()
    }
    assert not any(ros.values()), {m: r for m, r in ros.items() if r}

    def circle_from(start):
        stack = [(start, [start])]
        while stack:
            node, path = stack.pop()
            for nxt in graph[node]:
                if nxt == start:
                    return path + [start]
                if nxt not in path:
                    stack.append((nxt, path + [nxt]))
        return None

    circles = [c for c in (circle_from(m) for m in graph) if c]
    assert not circles, circles


def test_the_table_of_contents_lists_every_module():
    doc = (CORE / '__init__.py').read_text().split('"""')[1]
    missing = [p.stem for p in CORE.glob('*.py') if p.stem != '__init__' and f'{p.stem}.py' not in doc]
    assert not missing, missing
