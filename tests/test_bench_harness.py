"""The benchmark harness end to end: runner (inline, process pool, Dask), resume, reports, compare, sweeps, main."""

import base64
import json
import math
import os
import signal
import sqlite3
import subprocess
import sys
import time
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import yaml

from benchmarks import cli, registry
from benchmarks.report import report_document
from benchmarks.runner import execute, run_case
from benchmarks.store import Store
from benchmarks.suite import load_suite

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = ["raw", "shadow", "stray-point"]
TINY = {"name": "tiny", "cases": [
    {"name": "leaf-{distance_m}m", "scene": {"generator": "plate-leaf"}, "vary": {"distance_m": [3.0, 5.0]}},
    {"name": "edge", "scene": {"builtin": "knife-edge"}, "targets": ["plate"]},
]}
_TIMING_KEYS = ("runtime_s", "peak_mem_mb", "simulate_s", "finished")


@pytest.fixture(scope="module")
def tiny_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("suite") / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY))
    return path


@pytest.fixture(scope="module")
def tiny_run(tiny_path, tmp_path_factory):
    """The tiny suite run inline (one process): (db path, run id)."""
    db = tmp_path_factory.mktemp("db") / "results.sqlite"
    with Store(db) as store:
        outcome = execute(load_suite(str(tiny_path)), registry.resolve(VARIANTS), store, workers=0, progress=False)
    return db, outcome.run_id


def scores(db, run_id):
    """Result rows without timing fields, keyed by (case, variant)."""
    with Store(db) as store:
        rows = store.results(run_id)
    return {(r["case_name"], r["variant"]): {k: v for k, v in r.items() if k not in _TIMING_KEYS + ("run_id",)}
            for r in rows}


def same_scores(a, b) -> bool:
    """Equal scores, floats to 1e-12 relative: numpy's SIMD reductions may round the last bit differently with
    the memory alignment of an array, which differs between processes (the scans themselves are bit-identical)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_scores(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_scores(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-15) or (math.isnan(a) and math.isnan(b))
    return a == b


def test_inline_run_stores_every_pair_with_consistent_scores(tiny_run):
    db, run_id = tiny_run
    rows = scores(db, run_id)
    assert len(rows) == 3 * len(VARIANTS)
    with Store(db) as store:
        assert store.run_info(run_id)["status"] == "complete"
        assert all(r["runtime_s"] > 0 and r["simulate_s"] > 0 for r in store.results(run_id))
    for case in ("leaf-3.0m", "leaf-5.0m", "edge"):
        raw, shadow = rows[(case, "raw")]["metrics"]["targets"][0], rows[(case, "shadow")]["metrics"]["targets"][0]
        assert rows[(case, "raw")]["error"] is None
        assert raw["rop_before"] == shadow["rop_before"] > 0.05, "edge outliers exist before any filter"
        assert raw["rop_after"] == raw["rop_before"] and raw["good_points_lost"] == 0.0
        assert shadow["rop_after"] < 0.2 * shadow["rop_before"]
    leaf = rows[("leaf-5.0m", "raw")]["metrics"]["targets"][0]
    assert leaf["object_type"] == "leaf" and leaf["range_m"] == pytest.approx(5.0, abs=0.05)
    assert leaf["area_true_m2"] > 0 and -0.5 < leaf["area_rel_err"] < 0.5
    # A flat leaf seen whole: its visible area is its area, and so are the two errors.
    assert leaf["area_seen_rel_err"] == pytest.approx(leaf["area_rel_err"], abs=0.02)
    assert "area_rel_err" not in rows[("edge", "raw")]["metrics"]["targets"][0], "the knife-edge plate has no area truth"


def test_process_pool_gives_the_same_scores(tiny_path, tiny_run, tmp_path):
    with Store(tmp_path / "pool.sqlite") as store:
        outcome = execute(load_suite(str(tiny_path)), registry.resolve(VARIANTS), store, workers=2, progress=False)
    assert same_scores(scores(tmp_path / "pool.sqlite", outcome.run_id), scores(*tiny_run))


def test_dask_local_cluster_gives_the_same_scores(tiny_path, tiny_run, tmp_path):
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, host="127.0.0.1", protocol="tcp://",
                      dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        with Store(tmp_path / "dask.sqlite") as store:
            outcome = execute(load_suite(str(tiny_path)), registry.resolve(VARIANTS), store,
                              scheduler=cluster.scheduler_address, progress=False)
    assert same_scores(scores(tmp_path / "dask.sqlite", outcome.run_id), scores(*tiny_run))


def _run_suite_file(tmp_path, suite, variants, **options):
    path = tmp_path / f"{suite['name']}.yaml"
    path.write_text(yaml.safe_dump(suite))
    with Store(tmp_path / "r.sqlite") as store:
        outcome = execute(load_suite(str(path)), variants, store, workers=1, progress=False, **options)
        assert store.run_info(outcome.run_id)["status"] == "complete"
        return {(r["case_name"], r["variant"]): r for r in store.results(outcome.run_id)}


def test_worker_pool_records_memory_errors(tmp_path):
    suite = {"name": "greedy", "cases": [{"name": "big-leaf", "scene": {"generator": "plate-leaf", "distance_m": 0.8}}]}
    variants = registry.resolve(["sor", "raw"], {"sor": {"k": 20000}})  # 30k points x 20k neighbours: > 9 GB
    rows = _run_suite_file(tmp_path, suite, variants, memory_limit_gb=1.5)
    assert "MemoryError" in rows[("big-leaf", "sor")]["error"]
    assert rows[("big-leaf", "raw")]["error"] is None


def test_worker_pool_replaces_a_silent_worker(tmp_path):
    suite = {"name": "slow", "cases": [
        {"name": "orchard", "scene": {"builtin": "orchard-row"}, "scanner": {"step_deg": 0.04}},  # > 20 s
        {"name": "edge", "scene": {"builtin": "knife-edge"}, "targets": ["plate"]}]}
    rows = _run_suite_file(tmp_path, suite, registry.resolve(["raw"]), timeout_s=8.0)
    assert "no result within 8 s" in rows[("orchard", "raw")]["error"]
    assert rows[("edge", "raw")]["error"] is None and rows[("edge", "raw")]["metrics"]["targets"]


def test_height_field_cases_run_only_height_field_methods(tmp_path):
    suite = {"name": "hf", "cases": [{"name": "hemisphere", "scene": {
        "heightfield": "hemisphere", "side": 31, "alpha_noise_deg": 1.4}, "params": {"prop-sfs": {
            "n_smooth": 5, "quantization": "percentile", "eps_alpha": 0.2, "alpha_max_deg": 85, "rim_px": 0}}}]}
    path = tmp_path / "hf.yaml"
    path.write_text(yaml.safe_dump(suite))
    with Store(tmp_path / "r.sqlite") as store:
        outcome = execute(load_suite(str(path)), registry.resolve(["raw", "buffer"]), store, workers=0, progress=False)
        rows = store.results(outcome.run_id)
        assert store.run_info(outcome.run_id)["status"] == "complete"
    assert [r["variant"] for r in rows] == ["buffer"]
    (score,) = rows[0]["metrics"]["targets"]
    assert rows[0]["params"]["n_smooth"] == 20 and rows[0]["case_spec"]["params"]["prop-sfs"]["n_smooth"] == 5
    assert score["object_type"] == "heightfield" and score["completeness"] > 0.9
    assert score["within_5pct"] > 0.9, "thesis: > 95 % within 5 % of the radius at 1.4 deg noise"


def test_woody_variants_score_woody_objects(tmp_path):
    import woody

    if not hasattr(woody, "step"):
        pytest.skip("the woody package of this checkout has no reconstruction methods yet")
    suite = {"name": "wood", "cases": [{"name": "branch", "scene": {"generator": "branch", "radius_m": 0.05},
                                        "scanner": {"step_deg": 0.05}, "params": {"step": {"r_max_m": 0.1}}}]}
    path = tmp_path / "wood.yaml"
    path.write_text(yaml.safe_dump(suite))
    with Store(tmp_path / "r.sqlite") as store:
        outcome = execute(load_suite(str(path)), registry.resolve(["raw", "step", "cylinders"]), store, workers=0,
                          progress=False)
        rows = {r["variant"]: r for r in store.results(outcome.run_id)}
    assert rows["raw"]["metrics"]["targets"] == [], "leaf variants find no leaf on a branch"
    with Store(tmp_path / "r.sqlite") as store:
        summaries = {r["variant"]: r for r in report_document(store, outcome.run_id)["rows"]}
    for name in ("step", "cylinders"):
        assert rows[name]["error"] is None, rows[name]["error"]
        (score,) = rows[name]["metrics"]["targets"]
        assert score["target"] == "branch" and score["n_points"] > 100 and 0 <= score["wood_completeness"] <= 1
        assert score["volume_true_m3"] == pytest.approx(np.pi * 0.05 ** 2 * 0.6, rel=1e-6)
        assert score["volume_rel_err"] == pytest.approx(score["volume_rec_m3"] / score["volume_true_m3"] - 1)
        assert summaries[name]["diameter_err_median_m"] == pytest.approx(score["diameter_err_mae_m"])
        assert summaries[name]["volume_rel_err"] == pytest.approx(abs(score["volume_rel_err"]))
        assert score["dbh_true_m"] is None and summaries[name]["dbh_err_median_m"] is None  # a 0.6 m branch
    assert rows["step"]["params"]["r_max_m"] == 0.3 and rows["step"]["case_spec"]["params"] == {"step": {"r_max_m": 0.1}}


def test_a_failing_case_is_recorded_not_fatal():
    case = {"name": "bad", "scene": {"generator": "plate-leaf"}, "scanner": {"step_deg": -1.0}, "seed": 0,
            "targets": None}
    rows = run_case(case, [{"name": "raw", "family": "raw", "params": {"mesh_max_edge_m": 0.01, "mesh_smoothing_m": 0.002}}])
    assert len(rows) == 1 and "step_deg" in rows[0]["error"] and rows[0]["metrics"] == {"targets": []}


def _stored_rows(db):
    try:
        with sqlite3.connect(db, timeout=5) as connection:
            return connection.execute("SELECT case_name, variant, finished FROM results").fetchall()
    except sqlite3.OperationalError:  # not created yet
        return []


def test_resume_after_a_killed_run_neither_redoes_nor_loses_cases(tmp_path):
    suite = {"name": "killable", "cases": [{"name": "leaf-{incidence_deg}", "scene": {
        "generator": "plate-leaf", "distance_m": 1.0}, "vary": {"incidence_deg": [0, 10, 20, 30, 40, 50]}}]}
    (tmp_path / "killable.yaml").write_text(yaml.safe_dump(suite))
    db = tmp_path / "results.sqlite"
    command = [sys.executable, "-m", "benchmarks.cli", "run", "--suite", str(tmp_path / "killable.yaml"),
               "--db", str(db), "-o", str(tmp_path / "out"), "--workers", "1", "--variants", "raw", "shadow",
               "--quiet"]
    process = subprocess.Popen(command, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 90
    while len(_stored_rows(db)) < 2 and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    os.killpg(process.pid, signal.SIGKILL)
    assert process.wait(timeout=30) == -signal.SIGKILL, "the run finished before it could be killed"
    before = {(case, variant): finished for case, variant, finished in _stored_rows(db)}
    done_cases = len({case for case, variant in before if (case, "shadow") in before})
    assert 2 <= len(before) < 12 and done_cases < 6

    resumed = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert f"(resumed): {6 - done_cases} case(s) run, {done_cases} already done" in resumed.stderr
    after = {(case, variant): finished for case, variant, finished in _stored_rows(db)}
    assert len(after) == 12
    assert all(after[pair] == finished for pair, finished in before.items()), "finished cases are not redone"
    with sqlite3.connect(db) as connection:
        assert connection.execute("SELECT status FROM runs").fetchall() == [("complete",)]


class _CheckedHTML(HTMLParser):
    """Checks that tags nest properly and collects images and tables."""

    VOID = {"meta", "img", "br", "hr", "link", "input"}

    def __init__(self):
        super().__init__()
        self.stack, self.images, self.tables = [], [], 0

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.images.append(dict(attrs)["src"])
        elif tag not in self.VOID:
            self.stack.append(tag)
        self.tables += tag == "table"

    def handle_endtag(self, tag):
        assert self.stack and self.stack.pop() == tag, f"misnested </{tag}>"


def test_cli_run_writes_well_formed_reports(tiny_path, tmp_path, capsys):
    db, out = tmp_path / "results.sqlite", tmp_path / "out"
    argv = ["run", "--suite", str(tiny_path), "--db", str(db), "-o", str(out), "--workers", "0", "--quiet",
            "--variants", "raw", "shadow", "--set", "shadow.min_angle_deg=5"]
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "ROP after" in printed and "NOT MET" in printed
    parser = _CheckedHTML()
    parser.feed((out / "report.html").read_text())
    parser.close()
    assert parser.stack == [], parser.stack
    assert parser.tables >= 2 and len(parser.images) >= 3
    for src in parser.images:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    document = json.loads((out / "report.json").read_text())
    assert [r["variant"] for r in document["rows"]] == ["raw", "shadow"]

    assert cli.main(["report", "latest", "--db", str(db), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    required = {"suite", "variant", "rop_before", "rop_after", "rop_reduction", "good_points_lost",
                "area_rel_err_median", "elevation_err_median_deg", "azimuth_err_median_deg", "diameter_err_median_m",
                "volume_rel_err", "runtime_s"}
    assert all(required <= set(r) for r in printed["rows"])
    assert cli.main(["report", "latest", "--db", str(db), "-o", str(tmp_path / "again.json")]) == 0
    assert json.loads((tmp_path / "again.json").read_text()) == printed  # a .json path gets the JSON, not HTML
    raw, shadow = printed["rows"]
    assert raw["suite"] == "tiny" and raw["rop_reduction"] == 0.0 and shadow["rop_reduction"] > 0.8
    assert raw["diameter_err_median_m"] is None and raw["volume_rel_err"] is None
    assert [(r["scene"], r["variant"]) for r in printed["by_scene"]] == [
        ("plate-leaf", "raw"), ("plate-leaf", "shadow"), ("knife-edge", "raw"), ("knife-edge", "shadow")]
    with Store(db) as store:
        assert store.results(store.resolve("latest"))[-1]["params"]["min_angle_deg"] == 5

    assert cli.main(["report", "nothing-like-this", "--db", str(db)]) == 2
    assert "no run match" in capsys.readouterr().err


def test_compare_flags_regressions_beyond_noise(tiny_run, capsys):
    db, run_a = tiny_run
    with Store(db) as store:
        rows = store.results(run_a)
        same = store.create_run("tiny", "x", {}, "same", commit="c")
        store.add_results(same, rows)
        worse = store.create_run("tiny", "x", {}, "worse", commit="c")
        for r in rows:
            if r["variant"] == "shadow":
                r["metrics"] = {"targets": [{**leaf, "rop_after": leaf["rop_after"] + 0.05}
                                           for leaf in r["metrics"]["targets"]]}
        store.add_results(worse, rows)
    assert cli.main(["compare", run_a, same, "--db", str(db)]) == 0
    assert "0 regression(s)" in capsys.readouterr().out
    assert cli.main(["compare", run_a, worse, "--db", str(db), "--changes"]) == 1
    printed = capsys.readouterr().out
    assert "1 regression(s)" in printed
    assert [line.split()[:2] for line in printed.splitlines() if "regression" in line and "(s)" not in line] == \
        [["shadow", "rop_after"]]


def test_sweep_command_writes_table_and_plot(tmp_path, capsys):
    argv = ["sweep", "distance", "--values", "3", "5", "--variants", "raw", "shadow", "--workers", "0", "--quiet",
            "--db", str(tmp_path / "r.sqlite"), "-o", str(tmp_path / "sw")]
    assert cli.main(argv) == 0
    lines = (tmp_path / "sw" / "sweep-distance.csv").read_text().splitlines()
    assert lines[0].split(",")[:3] == ["value", "n_targets", "rop_before"] and len(lines) == 3
    assert "rop_after:shadow" in lines[0]
    assert (tmp_path / "sw" / "sweep-distance.png").read_bytes()[:4] == b"\x89PNG"
    assert "sweep distance" in capsys.readouterr().out


def test_main_job_end_to_end(tiny_path, tmp_path, capsys):
    out = tmp_path / "bench-out"
    assert cli.main(["main", "-o", str(out), "--suite", str(tiny_path), "--workers", "0", "--quiet",
                     "--variants", "raw", "shadow"]) == 0
    printed = capsys.readouterr().out
    assert "ROP red." in printed and "goal:" in printed
    for name in ("report.html", "report.json", "results.sqlite", "sweep-distance.csv", "sweep-incidence.png"):
        assert (out / name).is_file()
    document = json.loads((out / "report.json").read_text())
    assert [s["kind"] for s in document["sweeps"]] == ["distance", "incidence"]
    assert all(len(s["table"]) >= 5 for s in document["sweeps"])


def test_case_scanner_overrides_reach_the_window_and_the_model():
    from benchmarks.runner import simulate_case
    from benchmarks.suite import Case

    window = {"theta_deg": [-0.1, 0.1], "psi_deg": [89.9, 90.1]}
    _, scan = simulate_case(Case("k", {"builtin": "knife-edge"}, {"window": window, "step_deg": 0.036}, 0))
    assert scan.shape == (6, 6)
    assert scan.scanner.model.step_deg == 0.036
    # A built-in scene whose window has its own step still takes the case's step.
    _, scan = simulate_case(Case("c", {"builtin": "cylinder-50cm"}, {"step_deg": 0.5}, 0))
    assert np.degrees(np.median(np.diff(scan.theta, axis=1))) == pytest.approx(0.5)


def test_showcase_is_a_leaf_case_and_none_without_leaves():
    """The before/after figure needs leaf scores: woody-only runs have none and get no showcase."""
    from benchmarks.report import pick_showcase

    def row(name, scene, target):
        return {"error": None, "case_name": name, "case_spec": {"name": name, "scene": scene}, "runtime_s": 1.0,
                "metrics": {"targets": [target]}}

    woody = row("leafless-tree", {"builtin": "leafless-tree"}, {"target": "trunk", "volume_rel_err": 0.1})
    leaf = row("leaf", {"builtin": "leaf-1.5m"}, {"target": "leaf", "object_type": "leaf", "rop_before": 0.2})
    assert pick_showcase([woody]) is None
    assert pick_showcase([woody, leaf])["name"] == "leaf"


def test_showcase_leaves_out_cases_too_long_to_run_again():
    """The figure re-runs its case's variants: a case whose variants ran longer than the limit is never shown."""
    from benchmarks.report import SHOWCASE_MAX_S, pick_showcase

    def row(name, runtime_s):
        return {"error": None, "case_name": name, "case_spec": {"name": name, "scene": {"builtin": "leaf-1.5m"}},
                "runtime_s": runtime_s, "metrics": {"targets": [{"target": "leaf", "object_type": "leaf",
                                                                   "rop_before": 0.2}]}}

    long_case = [row("canopy", 0.6 * SHOWCASE_MAX_S), row("canopy", 0.6 * SHOWCASE_MAX_S)]  # two variants
    assert pick_showcase(long_case) is None
    assert pick_showcase(long_case + [row("leaf", 0.9 * SHOWCASE_MAX_S)])["name"] == "leaf"


def test_invalid_cases_are_refused_and_failed_results_exit_non_zero(tiny_path, tmp_path, capsys, monkeypatch):
    suite = tmp_path / "bad.yaml"
    suite.write_text(yaml.safe_dump({"name": "bad", "cases": [
        {"name": "behind-the-scanner", "scene": {"generator": "single-leaf", "distance_m": -1.5}}]}))
    out = ["--db", str(tmp_path / "r.sqlite"), "-o", str(tmp_path / "out"), "--workers", "0", "--quiet"]
    assert cli.main(["run", "--suite", str(suite), "--variants", "raw", *out]) == 2
    assert "distance_m is a length or distance in metres and must be positive" in capsys.readouterr().err
    assert not (tmp_path / "r.sqlite").exists(), "nothing runs before the suite is checked"

    def boom(scan, mask):
        raise RuntimeError("the method broke")

    monkeypatch.setitem(registry._VARIANTS, "boom", registry.Variant("boom", "filter", boom, {}, "fails"))
    assert cli.main(["run", "--suite", str(tiny_path), "--variants", "raw", "boom", *out]) == 1
    err = capsys.readouterr().err
    assert "3 result(s) failed; the first: case" in err and "variant 'boom': RuntimeError: the method broke" in err


_ORPHAN = """
import multiprocessing, time
from benchmarks.pool import _Slot
from benchmarks.runner import _warm_up, case_rows
slot = _Slot(multiprocessing.get_context("spawn"), None, case_rows, _warm_up)
while not slot.ready:  # the worker has warmed up and waits for a case
    slot.collect()
    time.sleep(0.1)
try:
    print(slot.process.pid, flush=True)
    time.sleep(600)
except KeyboardInterrupt:
    pass
"""


@pytest.mark.parametrize("how", ["SIGKILL to the run", "Ctrl-C to the process group"])
def test_workers_end_with_their_run_without_tracebacks(tmp_path, how):
    """A killed or interrupted benchmark run leaves no worker behind, and no worker prints a traceback."""
    stderr = tmp_path / "stderr.txt"
    with open(stderr, "w") as err:
        parent = subprocess.Popen([sys.executable, "-c", _ORPHAN], cwd=ROOT, stdout=subprocess.PIPE, stderr=err,
                                  text=True, start_new_session=True,
                                  preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        worker = int(parent.stdout.readline())
        ignored = int(next(line for line in open(f"/proc/{worker}/status") if line.startswith("SigIgn:")).split()[1], 16)
        assert ignored & (1 << (signal.SIGINT - 1)), "a worker must leave Ctrl-C to its run"
        if how.startswith("SIGKILL"):
            os.kill(parent.pid, signal.SIGKILL)
        else:
            os.killpg(parent.pid, signal.SIGINT)
        parent.wait(timeout=30)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                os.kill(worker, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
        else:
            os.kill(worker, signal.SIGKILL)
            raise AssertionError(f"the worker outlived its run ({how}) by 10 s")
    time.sleep(0.5)
    assert "Traceback" not in stderr.read_text()
