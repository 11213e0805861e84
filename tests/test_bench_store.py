"""The SQLite results store: runs, results, resolution of run names, concurrent writers."""

import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.errors import BenchError
from benchmarks.store import Store

ROOT = Path(__file__).resolve().parents[1]


def row(case, variant="raw", **metrics):
    return {"case_name": case, "variant": variant, "family": "raw", "params": {"k": 1}, "case_spec": {"name": case},
            "metrics": {"targets": [], **metrics}, "runtime_s": 0.5, "peak_mem_mb": 3.0, "simulate_s": 0.1,
            "error": None}


def test_runs_results_and_resolution(tmp_path):
    with Store(tmp_path / "r.sqlite") as store:
        first = store.create_run("quick", "sd", {"v": 1}, "cfg", commit="abc")
        assert store.add_results(first, [row("a"), row("b", "sor")]) == 2
        assert store.add_results(first, [row("a"), row("c")]) == 1, "a stored result is never replaced"
        assert store.done_pairs(first) == {("a", "raw"), ("b", "sor"), ("c", "raw")}
        stored = store.results(first)
        assert stored[0]["params"] == {"k": 1} and stored[0]["metrics"] == {"targets": []}
        assert store.find_resumable("cfg", "abc") == first
        assert store.find_resumable("cfg", "other-commit") is None
        store.finish_run(first)
        assert store.find_resumable("cfg", "abc") is None
        info = store.run_info(first)
        assert info["status"] == "complete" and info["git_commit"] == "abc" and info["machine"]["cpus"] >= 1
        second = store.create_run("quick", "sd", {"v": 1}, "cfg", commit="abc")
        assert store.resolve("latest") == second
        assert store.resolve(first) == first
        assert store.resolve(second[:-2]) == second
        with pytest.raises(BenchError, match="no run match"):
            store.resolve("1999")
        store.set_notes(second, {"sweeps": [first]})
        assert store.run_info(second)["notes"] == {"sweeps": [first]}


def test_empty_and_corrupt_stores(tmp_path):
    with Store(tmp_path / "empty.sqlite") as store:
        with pytest.raises(BenchError, match="no run yet"):
            store.resolve("latest")
    bad = tmp_path / "bad.sqlite"
    bad.write_bytes(b"this is not a database" * 100)
    with pytest.raises(BenchError, match="bad.sqlite"):
        Store(bad)


_WRITER = """
import sys
from benchmarks.store import Store
path, run, name = sys.argv[1:]
with Store(path) as store:
    for i in range(80):
        store.add_results(run, [{"case_name": f"{name}-{i}", "variant": "raw", "family": "raw", "params": {},
                                 "case_spec": {}, "metrics": {"targets": [], "i": i}, "runtime_s": 0.0,
                                 "peak_mem_mb": None, "simulate_s": 0.0, "error": None}])
"""


def test_concurrent_writers_do_not_corrupt_the_store(tmp_path):
    path = tmp_path / "shared.sqlite"
    with Store(path) as store:
        run = store.create_run("quick", "sd", {}, "cfg", commit="abc")
    writers = [subprocess.Popen([sys.executable, "-c", _WRITER, str(path), run, f"w{k}"], cwd=ROOT)
               for k in range(3)]
    assert all(w.wait(timeout=120) == 0 for w in writers)
    with Store(path) as store:
        pairs = store.done_pairs(run)
    assert len(pairs) == 240
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_read_commands_never_create_or_change_files(tmp_path, capsys):
    from benchmarks import cli

    missing = tmp_path / "typo.sqlite"
    with pytest.raises(BenchError, match="no results database"):
        Store(missing, create=False)
    assert not missing.exists()
    empty_json = tmp_path / "report.json"
    empty_json.write_bytes(b"")
    for argv in (["report", "latest", "--db", str(empty_json)], ["compare", "a", "b", "--db", str(missing)]):
        assert cli.main(argv) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert empty_json.read_bytes() == b"" and not missing.exists()


def test_latest_is_the_latest_suite_run_not_a_sweep(tmp_path):
    with Store(tmp_path / "r.sqlite") as store:
        store.create_run("sweep-distance", "sd", {}, "a", commit="c")
        suite = store.create_run("quick", "sd", {}, "b", commit="c")
        store.create_run("sweep-incidence", "sd", {}, "c", commit="c")
        assert store.resolve("latest") == suite
    with Store(tmp_path / "r.sqlite", create=False) as store:
        assert store.resolve("latest") == suite
    with Store(tmp_path / "sweeps.sqlite") as store:
        only = store.create_run("sweep-distance", "sd", {}, "a", commit="c")
        assert store.resolve("latest") == only
