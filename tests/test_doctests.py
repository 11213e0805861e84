"""The Examples sections of the main entry points run as doctests, so ``make test`` executes them
(issue 13 item 6).

``EXAMPLES`` maps a module to the public functions that must carry a runnable example; every
doctest in those modules runs (each example is small: a few seconds on one core). Add a module
here when one of its entry points gains an Examples section.
"""

import doctest
import importlib

import pytest

EXAMPLES = {
    "tlssim.simulate": ("simulate",),
    "leafsfs.engine": ("reconstruct_heights",),
    "leafsfs.reconstruct": ("reconstruct",),
    "woody.step": ("step",),
    "benchmarks.runner": ("execute",),
    "woody.cylinders": ("follow_cylinders",),
    "woody.circles": ("fit_circle", "algebraic_circle"),
    "woody.ground": ("ground_grid",),
    "woody.density": ("point_spacing", "voxel_subsample"),
    "woody.normals": ("pca_normals", "orient_outward"),
    "woody.pipe": ("pipe_radii",),
    "woody.leafwood": ("separate_wood",),
}


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_examples_run(name):
    module = importlib.import_module(name)
    missing = [f for f in EXAMPLES[name] if ">>> " not in (getattr(module, f).__doc__ or "")]
    assert not missing, f"{name}: no example in the docstring of {', '.join(missing)}"
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS, report=False)
    assert result.attempted > 0
    assert result.failed == 0, f"{result.failed} of {result.attempted} doctest lines of {name} failed (output above)"
