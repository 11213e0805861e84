"""Shared fixtures: every test that traces rays uses the CPU (LLVM) backend."""

import pytest


@pytest.fixture(scope="session")
def llvm():
    """Activate the Mitsuba LLVM variant once per test session."""
    from tlssim.backend import select_backend

    return select_backend("llvm")
