"""The one-way layering of the packages: scenes <- tlssim <- leafsfs, woody <- benchmarks.

Imports are read from the source (every ``import`` statement, function
bodies included), so that an import hidden in a function counts as much as
one at the top of a module.
"""

import ast
import collections
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Layer of every package: a module may import its own package and those of lower layers only.
LAYERS = {"scenes": 0, "tlssim": 1, "leafsfs": 2, "woody": 2, "benchmarks": 3}


def _modules() -> dict[str, Path]:
    modules = {}
    for package in LAYERS:
        for path in sorted((ROOT / package).rglob("*.py")):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            modules[name.removesuffix(".__init__")] = path
    return modules


def _imports(name: str, path: Path) -> list[tuple[int, str]]:
    """``(line, imported module)`` of every import statement of a module, relative ones resolved."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")[:len(name.split(".")) - node.level + (path.name == "__init__.py")]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module
            found.append((node.lineno, module))
            found += [(node.lineno, f"{module}.{alias.name}") for alias in node.names]
    return found


MODULES = _modules()


def test_the_walk_sees_imports_inside_functions():
    imports = _imports("x", ROOT / "tests" / "test_architecture.py")
    assert any(module == "tlssim.scanner" for _, module in imports)  # the import in the last test's body


def test_no_package_imports_one_above_or_beside_it():
    upward = []
    for name, path in MODULES.items():
        package = name.split(".")[0]
        for line, module in _imports(name, path):
            other = module.split(".")[0]
            if other in LAYERS and other != package and LAYERS[other] >= LAYERS[package]:
                upward.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
    assert not upward, "imports against the layering:\n" + "\n".join(upward)


def test_no_import_cycle_between_modules():
    graph = collections.defaultdict(set)
    for name, path in MODULES.items():
        for _, module in _imports(name, path):
            if module in MODULES and module != name and not name.startswith(module + "."):
                graph[name].add(module)
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(node):  # Tarjan's strongly connected components
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in graph[node]:
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while not component or component[-1] != node:
                component.append(stack.pop())
                on_stack.discard(component[-1])
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in list(MODULES):
        if node not in index:
            visit(node)
    assert not cycles, f"modules that import each other: {cycles}"


def test_the_contract_and_reconstruction_import_without_the_simulator():
    """Reconstructing a real scan loads neither Mitsuba, Dr.Jit nor the scene library."""
    script = ("import sys, leafsfs, woody, woody.trunk, woody.dbh, woody.leafwood, tlssim, tlssim.formats, tlssim.scan, "
              "tlssim.pattern, tlssim.scanner; "
              "from tlssim import Scan, ScannerDescription, ScannerPose, ScanWindow, ScannerModel; "
              "from tlssim.scan import grid_to_xyz; "
              "print(sorted({m.split('.')[0] for m in sys.modules} & {'mitsuba', 'drjit', 'scenes'}))")
    out = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_the_simulator_loads_on_first_use_and_keeps_its_name():
    """``tlssim.simulate`` stays the function even after its submodule of the same name is imported."""
    script = ("import sys, tlssim; from tlssim.simulate import setup_from_section; "
              "module = sys.modules['tlssim.simulate']; "
              "assert tlssim.simulate is module.simulate and tlssim.setup_from_section is setup_from_section; "
              "assert tlssim.ScanSetup is module.ScanSetup; print('ok')")
    out = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "ok"


@pytest.mark.parametrize("field", ["beam_waist_radius_m", "divergence_deg"])
def test_scenes_default_beam_is_the_faro_preset_beam(field):
    from scenes import primitives
    from tlssim.scanner import get_preset

    default = {"beam_waist_radius_m": primitives.DEFAULT_BEAM_WAIST_RADIUS_M,
               "divergence_deg": primitives.DEFAULT_DIVERGENCE_DEG}[field]
    model = get_preset("faro-ls880")
    assert default == getattr(model, field)
    assert primitives.facet_size_m(3.0) == pytest.approx(0.25 * 2 * model.beam_radius_m(3.0), rel=1e-15)
