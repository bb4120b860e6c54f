"""The package reads from its tree: every module sits in a wing, the wings import only the wings
above them (eqhrl_ros/__init__.py lists them in that order), and no module or function is
longer than a reader takes in at once."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / 'eqhrl_ros'
# Highest first: a wing may import itself and the wings before it.
WINGS = ('core', 'files', 'parameters', 'nodes', 'experiments', 'reports', 'cli')
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80


def python_files():
    return sorted(p for p in PACKAGE.rglob('*.py') if '__pycache__' not in p.parts)


def wing_imports(path: Path) -> set:
    """The package's wings that ``path`` imports (relative or absolute imports of eqhrl_ros)."""
    rel = path.relative_to(PACKAGE)
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level > 1:
            # from ..x import y, seen from eqhrl_ros/<wing>/.../module.py
            base = list(rel.parts[:-1])[: len(rel.parts) - node.level]
            parts = base + [m for m in (node.module or '').split('.') if m]
            found.add(parts[0] if parts else node.names[0].name)
        elif isinstance(node, ast.ImportFrom) and (node.module or '').startswith('eqhrl_ros.'):
            found.add(node.module.split('.')[1])
    return found


def test_every_module_sits_in_a_wing_the_table_of_contents_lists():
    loose = [p.name for p in PACKAGE.glob('*.py') if p.name != '__init__.py']
    assert not loose, f'modules outside a wing: {loose}'
    packages = {p.parent.name for p in PACKAGE.glob('*/__init__.py')}
    assert packages == set(WINGS), packages
    contents = (PACKAGE / '__init__.py').read_text().split('"""')[1]
    listed = [line.split()[0][:-1] for line in contents.splitlines() if line and line.split()[0].endswith('/')]
    assert [w for w in listed if w in WINGS] == list(WINGS)


def test_wings_import_only_the_wings_above_them():
    upward = {}
    for path in python_files():
        rel = path.relative_to(PACKAGE)
        if len(rel.parts) < 2:
            continue
        wing = rel.parts[0]
        above = set(WINGS[: WINGS.index(wing) + 1])
        wrong = sorted(w for w in wing_imports(path) if w in WINGS and w not in above)
        if wrong:
            upward[str(rel)] = wrong
    assert not upward, upward


def test_no_module_over_500_lines_and_no_function_over_80():
    long_modules = {}
    long_functions = {}
    for path in python_files():
        text = path.read_text()
        rel = str(path.relative_to(PACKAGE))
        if len(text.splitlines()) > MAX_MODULE_LINES:
            long_modules[rel] = len(text.splitlines())
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    long_functions[f'{rel}:{node.name}'] = length
    assert not long_modules, long_modules
    assert not long_functions, long_functions
