"""A benchmark case too large for memory: simulated into tiles and scored window by window, as in one piece."""

import pytest

import leafsfs.tiled
from benchmarks import runner
from benchmarks.registry import get_variant
from benchmarks.runner import case_rows, variant_specs
from benchmarks.suite import Case
from tlssim.tiled import open_tiled


def test_a_tiled_case_scores_as_the_scan_in_one_piece(tmp_path, monkeypatch, llvm):
    # The 9 cm leaf 1.5 m away spans columns 25-213 of 309; cores of ~210 columns cut it near column 211.
    case = Case("leaf", {"builtin": "leaf-1.5m"}, {}, 5).to_dict()
    specs = variant_specs([get_variant("raw"), get_variant("fused")])
    whole = {row["variant"]: row for row in case_rows(case, specs)}
    monkeypatch.setenv("TLSBENCH_TILES", str(tmp_path))
    monkeypatch.setattr(runner, "TILED_SCAN_BYTES", 0)
    monkeypatch.setattr(runner, "TILED_WINDOW_BYTES", 1.0)  # the smallest core: one margin wide
    monkeypatch.setattr(leafsfs.tiled, "LEAF_SIZE_M", 0.09)
    tiled = {row["variant"]: row for row in case_rows(case, specs)}
    (scan_dir,) = tmp_path.iterdir()
    assert open_tiled(scan_dir).complete
    for name in ("raw", "fused"):
        a, b = whole[name], tiled[name]
        assert a["error"] is None and b["error"] is None, (a["error"], b["error"])
        assert [t["target"] for t in b["metrics"]["targets"]] == [t["target"] for t in a["metrics"]["targets"]]
        for ta, tb in zip(a["metrics"]["targets"], b["metrics"]["targets"]):
            assert tb["area_rel_err"] == pytest.approx(ta["area_rel_err"], abs=0.02)
            assert tb.get("found") == ta.get("found")
        assert b["metrics"]["case"]["n_pulses"] == a["metrics"]["case"]["n_pulses"]
    counts = tiled["fused"]["metrics"]["case"]
    assert counts["tiled_core_cols"] < 309 and counts["n_leaves"] == 1 and counts["n_regions"] == 1
