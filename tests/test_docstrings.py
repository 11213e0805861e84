"""Every public function or method with two or more parameters documents them in a numpydoc
``Parameters`` section whose names match its signature (issue 13 item 6).

The check reads the source (AST only, nothing is imported) and is enabled package by package:
``ENABLED`` maps a package to ``None`` (all its modules) or to the modules that comply so far.
A package not yet listed shows as skipped; add it here once it complies.
"""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("scenes", "tlssim", "leafsfs", "woody", "benchmarks")

ENABLED = {
    "scenes": None,
    "tlssim": None,
    "leafsfs": None,
    "woody": None,
    "benchmarks": None,
}

# ``name : type`` (several names may share one entry); ``*args`` and ``**kwargs`` may stand alone.
_ENTRY = re.compile(r"^(\*{0,2}\w+(?:\s*,\s*\*{0,2}\w+)*)\s+:\s*\S|^(\*{1,2}\w+)\s*$")


def _sections(doc):
    """Split a cleaned numpydoc docstring into {header: [lines]}."""
    lines = doc.splitlines()
    heads = [i for i in range(len(lines) - 1)
             if lines[i].strip() and set(lines[i + 1].strip()) == {"-"}
             and len(lines[i + 1].strip()) >= len(lines[i].strip())]
    out = {}
    for k, i in enumerate(heads):
        end = heads[k + 1] if k + 1 < len(heads) else len(lines)
        out[lines[i].strip()] = lines[i + 2:end]
    return out


def _documented(section):
    """Names of the ``name : type`` entries (lines at the section's own indentation)."""
    names = []
    for line in section:
        if not line.strip() or line[0].isspace():
            continue
        match = _ENTRY.match(line)
        if match is None:
            names.append(f"<not 'name : type': {line.strip()!r}>")
            continue
        names += [n.strip().lstrip("*") for n in (match.group(1) or match.group(2)).split(",")]
    return names


def _signature(fn):
    a = fn.args
    names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs if x.arg not in ("self", "cls")]
    names += [x.arg for x in (a.vararg, a.kwarg) if x is not None]
    return names


def _public_functions(tree):
    def visit(body, prefix):
        for node in body:
            if getattr(node, "name", "_").startswith("_"):
                continue
            if isinstance(node, ast.ClassDef):
                yield from visit(node.body, f"{prefix}{node.name}.")
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield f"{prefix}{node.name}", node
    yield from visit(tree.body, "")


def _problems(path, root=ROOT):
    out = []
    for name, fn in _public_functions(ast.parse(path.read_text(), str(path))):
        params = _signature(fn)
        if len(params) < 2:
            continue
        where = f"{path.relative_to(root)}:{fn.lineno} {name}"
        section = _sections(ast.get_docstring(fn) or "").get("Parameters")
        if section is None:
            out.append(f"{where}: no Parameters section")
            continue
        documented = _documented(section)
        if documented != params:
            out.append(f"{where}: Parameters {documented} != signature {params}")
    return out


def _modules(package):
    only = ENABLED[package]
    files = sorted((ROOT / package).rglob("*.py"))
    if only is not None:
        files = [ROOT / package / m for m in only]
    return files


@pytest.mark.parametrize("package", [
    p if p in ENABLED else pytest.param(p, marks=pytest.mark.skip(reason="not yet compliant (issue 13 item 6)"))
    for p in PACKAGES])
def test_public_functions_document_their_parameters(package):
    files = _modules(package)
    assert files and all(f.is_file() for f in files), f"{package}: enabled modules missing"
    problems = [p for f in files for p in _problems(f)]
    assert not problems, f"{len(problems)} undocumented:\n" + "\n".join(problems)


def test_the_check_sees_a_mismatch(tmp_path):
    src = tmp_path / "m.py"
    src.write_text('def f(a, b):\n    """F.\n\n    Parameters\n    ----------\n    a : float\n'
                   '        A, m.\n    c : float\n        Stale.\n    """\n'
                   'class C:\n    def g(self, x, *rest):\n        """G.\n\n    Parameters\n'
                   '    ----------\n    x, *rest : int\n        Counts.\n    """\n'
                   '    def h(self, x, y):\n        pass\n')
    problems = _problems(src, tmp_path)
    assert len(problems) == 2
    assert "f: Parameters ['a', 'c'] != signature ['a', 'b']" in problems[0]
    assert "C.h: no Parameters section" in problems[1]
