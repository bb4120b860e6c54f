"""core/ is a library in five wings with no circles: no module reaches itself through its imports,
no wing imports one meant to stand above it, none imports ROS (the nodes are thin adapters over
it), and its table of contents lists every module."""

import ast
from pathlib import Path

CORE = Path(__file__).resolve().parents[2] / 'eqhrl_ros' / 'core'
# Lowest first: a module may import its own wing and the wings before it.
WINGS = ('data', 'envs', 'algorithm', 'experts', 'runs')


def modules() -> dict:
    """'wing.module' -> the core modules it imports (as 'wing.module'), and its other imports."""
    found = {}
    for path in CORE.glob('*/*.py'):
        if path.stem == '__init__':
            continue
        wing, name = path.parent.name, path.stem
        inside, outside = set(), set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level == 1:  # from .x import y, or from . import x
                    heads = [node.module] if node.module else [a.name for a in node.names]
                    inside |= {f'{wing}.{h.split(".")[0]}' for h in heads}
                elif node.level == 2:  # from ..wing.x import y, or from ..wing import x
                    other, _, rest = (node.module or '').partition('.')
                    heads = [rest] if rest else [a.name for a in node.names]
                    inside |= {f'{other}.{h.split(".")[0]}' for h in heads}
                elif node.level > 2:
                    outside.add('.' * node.level + (node.module or ''))  # out of core: refused below
                elif node.module:
                    outside.add(node.module)
            elif isinstance(node, ast.Import):
                outside |= {a.name for a in node.names}
        found[f'{wing}.{name}'] = (inside, outside)
    return found


def test_every_core_module_sits_in_a_wing():
    assert sorted(p.name for p in CORE.glob('*.py')) == ['__init__.py']
    assert sorted(p.name for p in CORE.iterdir() if p.is_dir() and p.name != '__pycache__') == sorted(WINGS)


def test_core_has_no_import_circles_no_upward_imports_and_no_ros():
    found = modules()
    graph = {m: inside for m, (inside, _) in found.items()}
    unknown = {m: sorted(d - graph.keys()) for m, d in graph.items() if d - graph.keys()}
    assert not unknown, unknown
    upward = {
        m: sorted(d for d in deps if WINGS.index(d.split('.')[0]) > WINGS.index(m.split('.')[0]))
        for m, deps in graph.items()
    }
    assert not any(upward.values()), {m: u for m, u in upward.items() if u}
    foreign = {
        m: sorted(d for d in out if d.startswith('.') or d.split('.')[0] in ('rclpy', 'std_msgs', 'eqhrl_interfaces'))
        for m, (_, out) in found.items()
    }
    assert not any(foreign.values()), {m: r for m, r in foreign.items() if r}

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


def test_the_table_of_contents_lists_every_module_under_its_wing():
    doc = (CORE / '__init__.py').read_text().split('"""')[1]
    sections = {}
    wing = None
    for line in doc.splitlines():
        head = line.split('/')[0] if line and not line.startswith(' ') and '/' in line.split()[0] else None
        if head in WINGS:
            wing = head
        elif wing and line.startswith('  ') and line.split()[0].endswith('.py'):
            sections.setdefault(wing, set()).add(line.split()[0][:-3])
    on_disk = {w: {p.stem for p in (CORE / w).glob('*.py') if p.stem != '__init__'} for w in WINGS}
    assert sections == on_disk
