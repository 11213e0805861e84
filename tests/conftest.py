"""Shared fixtures: the ray-tracing backends (the CPU's LLVM everywhere; a CUDA GPU where one is present) and the
hand-made Y tree of the woody tests."""

import pytest


def _has_backend(name):
    """Whether Dr.Jit can run the backend ``name`` ("llvm" or "cuda") on this machine."""
    try:
        import drjit as dr
    except ImportError:
        return False
    return dr.has_backend(getattr(dr.JitBackend, name.upper()))


#: Skips a test or parameter that needs a CUDA GPU where Dr.Jit finds none: the GPU path (``--backend cuda``) is
#: checked wherever one is present and never needed by the suite.
needs_cuda = pytest.mark.skipif(not _has_backend("cuda"), reason="no CUDA GPU here: the GPU path runs where one is")
#: Skips a test or parameter that needs the CPU backend where Dr.Jit cannot load libLLVM (a bare GPU machine).
needs_llvm = pytest.mark.skipif(not _has_backend("llvm"), reason="Dr.Jit finds no libLLVM here")


@pytest.fixture(scope="session")
def llvm():
    """Activate the Mitsuba LLVM variant once per test session."""
    from tlssim.backend import select_backend

    return select_backend("llvm")


@pytest.fixture(scope="module", params=[pytest.param("llvm", marks=needs_llvm), pytest.param("cuda", marks=needs_cuda)])
def backend(request):
    """Each backend this machine can run, in turn (LLVM always; CUDA where a GPU is present)."""
    return request.param


@pytest.fixture
def cuda_and_llvm():
    """Skips a test that compares the two backends unless this machine runs both (a GPU machine with libLLVM)."""
    missing = [name for name in ("cuda", "llvm") if not _has_backend(name)]
    if missing:
        pytest.skip(f"no {' or '.join(missing)} backend here: the backends are compared where both run")


@pytest.fixture(scope="session")
def y_tree():
    """A Y-shaped tree's truth cylinders: a 10 cm stem 0.8 m tall forking into two 6 cm arms (m)."""
    return [{"id": 0, "parent": -1, "order": 1, "branch": 0, "start": [0, 0, 0], "end": [0, 0, 0.8],
             "radius_m": 0.05, "radius_end_m": 0.05},
            {"id": 1, "parent": 0, "order": 2, "branch": 1, "start": [0, 0, 0.8], "end": [0.4, 0, 1.3],
             "radius_m": 0.03, "radius_end_m": 0.03},
            {"id": 2, "parent": 0, "order": 2, "branch": 2, "start": [0, 0, 0.8], "end": [-0.35, 0.1, 1.35],
             "radius_m": 0.03, "radius_end_m": 0.03}]
