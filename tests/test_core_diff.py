"""``tlssim diff`` / :func:`tlssim.compare.compare_scans` on hand-made scans with known differences."""

import numpy as np
import pytest

from tlssim.cli import main
from tlssim.compare import compare_scans
from tlssim.errors import ScanError
from tlssim.scan import Scan


def _scan(range_m, truth_id=None):
    theta, psi = np.meshgrid(np.linspace(-0.1, 0.1, range_m.shape[1]), np.linspace(1.4, 1.6, range_m.shape[0]))
    xyz = np.stack([range_m * np.sin(psi) * np.cos(theta), range_m * np.sin(psi) * np.sin(theta),
                    range_m * np.cos(psi)], axis=-1)
    return Scan(range_m, np.where(np.isfinite(range_m), 100.0, np.nan).astype(np.float32), theta, psi, xyz,
                truth_range=None if truth_id is None else range_m.copy(), truth_id=truth_id)


@pytest.fixture
def pair(tmp_path):
    """A 6 x 8 scan and a copy with 3 pulses 2 mm off, 5 pulses 0.5 mm off, one pulse lost and one object id changed."""
    rng = np.random.default_rng(4)
    base = 2.0 + rng.uniform(0, 0.5, (6, 8))
    ids = np.zeros((6, 8), dtype=np.int32)
    other = base.copy()
    other.flat[[1, 9, 17]] += 2e-3
    other.flat[[2, 3, 4, 5, 6]] -= 5e-4
    other.flat[40] = np.nan
    other_ids = ids.copy()
    other_ids.flat[12] = 3
    a, b = _scan(base, ids), _scan(other, other_ids)
    return a, b, a.save(tmp_path / "a.npz"), b.save(tmp_path / "b.npz")


def test_identical_scans_do_not_differ(pair):
    a, _, _, _ = pair
    report = compare_scans(a, a)
    for stats in report["layers"].values():
        assert stats["equal"] == 1.0 and stats["max"] == 0.0 and stats.get("differing", 0) == 0


def test_counts_match_the_planted_differences(pair):
    a, b, _, _ = pair
    layers = compare_scans(a, b, tolerance_m=1e-3)["layers"]
    rng = layers["range"]
    assert (rng["compared"], rng["only_a"], rng["only_b"], rng["differing"]) == (47, 1, 0, 3)
    assert rng["max"] == pytest.approx(2e-3, rel=1e-6)
    assert rng["equal"] == pytest.approx(39 / 47)
    assert layers["xyz"]["differing"] == 3  # a 2 mm range shift moves x by about 2 mm
    assert layers["truth_id"]["differing"] == 1
    assert compare_scans(a, b, tolerance_m=1e-4)["layers"]["range"]["differing"] == 8


def test_cli_exit_status_follows_tolerance_and_allowed_fraction(pair, capsys):
    _, _, path_a, path_b = pair
    assert main(["diff", str(path_a), str(path_a)]) == 0
    assert main(["diff", str(path_a), str(path_b)]) == 1  # 3 beyond 1 mm + 1 lost return = 4 of 48 pulses
    assert main(["diff", str(path_a), str(path_b), "--allow-fraction", str(4 / 48)]) == 0
    assert main(["diff", str(path_a), str(path_b), "--allow-fraction", str(3 / 48)]) == 1
    capsys.readouterr()
    assert main(["diff", str(path_a), str(path_b), "--json"]) == 1
    assert '"differing_fraction": 0.0833' in capsys.readouterr().out


def test_other_grid_is_refused(pair, tmp_path, capsys):
    a, _, path_a, _ = pair
    small = _scan(np.full((3, 8), 2.0))
    with pytest.raises(ScanError, match="grids differ"):
        compare_scans(a, small)
    assert main(["diff", str(path_a), str(small.save(tmp_path / "small.npz"))]) == 2
    assert "grids differ" in capsys.readouterr().err
