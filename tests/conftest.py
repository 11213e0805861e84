"""Shared fixtures: every test that traces rays uses the CPU (LLVM) backend; the hand-made Y tree of the woody tests."""

import pytest


@pytest.fixture(scope="session")
def llvm():
    """Activate the Mitsuba LLVM variant once per test session."""
    from tlssim.backend import select_backend

    return select_backend("llvm")


@pytest.fixture(scope="session")
def y_tree():
    """A Y-shaped tree's truth cylinders: a 10 cm stem 0.8 m tall forking into two 6 cm arms (m)."""
    return [{"id": 0, "parent": -1, "order": 1, "branch": 0, "start": [0, 0, 0], "end": [0, 0, 0.8],
             "radius_m": 0.05, "radius_end_m": 0.05},
            {"id": 1, "parent": 0, "order": 2, "branch": 1, "start": [0, 0, 0.8], "end": [0.4, 0, 1.3],
             "radius_m": 0.03, "radius_end_m": 0.03},
            {"id": 2, "parent": 0, "order": 2, "branch": 2, "start": [0, 0, 0.8], "end": [-0.35, 0.1, 1.35],
             "radius_m": 0.03, "radius_end_m": 0.03}]
