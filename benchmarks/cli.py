"""The ``tlsbench`` command line.

- ``tlsbench run --suite quick|standard|FILE [--variants ...] [--set V.P=X] [--scheduler ADDR] --db DB -o OUT``
  runs a suite (resuming an interrupted run of the same configuration) and
  writes ``OUT/report.html`` and ``OUT/report.json``;
- ``tlsbench report RUN [-o report.html] [--json]`` (RUN: an id, a unique id prefix or ``latest``);
- ``tlsbench compare RUN_A RUN_B`` flags regressions of B against A (exit status 1 when there are some);
- ``tlsbench sweep KIND [--scene GENERATOR] [--values ...]`` runs a stress sweep and writes its table and plot;
- ``tlsbench main -o DIR`` is the project's main job (``make bench``): the main suite with every
  registered variant, the distance and incidence sweeps, the store, the report and the headline table;
- ``tlsbench baseline update [--suite quick]`` rewrites the suite's committed baseline from a new (or stored) run;
- ``tlsbench check [--suite quick]`` runs the suite and compares it with the baseline (exit 1 on a regression);
- ``tlsbench history METRIC [--variant V] [--suite S] [--db DB]`` shows a metric across the stored commits (PNG);
- ``tlsbench experiment NAME`` and ``tlsbench perf NAME`` run the experiments and performance harnesses of
  :mod:`benchmarks.experiments`;
- ``tlsbench reproduce [NAME ...] [--list] [--quick]`` reproduces the sources' published tables and figures
  (:mod:`benchmarks.reproduce`), writes ``reproduction.html`` and ends with ``N/M rows within tolerance``;
- ``tlsbench budget --suite S [--case NAME] [--variant V]`` splits the outliers a leaf variant leaves on one
  case by their truth and by what the variant did (:mod:`benchmarks.budget`);
- ``tlsbench list`` shows suites, variants, scene generators and sweeps.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import yaml

from benchmarks import baseline, registry, summary, sweeps
from benchmarks.baseline import TIMING_BAND
from benchmarks.errors import BenchError
from benchmarks.experiments.cli import add_parsers as add_experiment_parsers
from benchmarks.generators import describe_generators
from benchmarks.reproduce.cli import add_parser as add_reproduce_parser
from benchmarks.runner import MEMORY_LIMIT_GB, TIMEOUT_S, execute
from benchmarks.store import Store
from benchmarks.suite import load_suite, suite_names
from tlssim.clitools import run_main

#: Suite of the main job: about 3 min on 2 cores with every registered variant (see the README).
MAIN_SUITE = "quick"
#: Sweeps of the main job (raw and every filter).
MAIN_SWEEPS = ("distance", "incidence")


def _assignments(items: list[str] | None, what: str) -> dict:
    """Parse ``KEY=VALUE`` items (values read as YAML scalars: numbers, booleans, null, strings)."""
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise BenchError(f"{what} must look like KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise BenchError(f"{what} {item!r}: the value is not a number, boolean or plain string") from None
    return out


def _overrides(items: list[str] | None) -> dict[str, dict]:
    """``--set VARIANT.PARAM=VALUE`` items as ``{variant: {param: value}}``."""
    out: dict[str, dict] = {}
    for key, value in _assignments(items, "--set").items():
        variant, dot, param = key.partition(".")
        if not dot:
            raise BenchError(f"--set needs VARIANT.PARAM=VALUE, got {key!r}")
        out.setdefault(variant, {})[param] = value
    return out


def _add_execution(p: argparse.ArgumentParser, db_default: str | None = "results.sqlite") -> None:
    p.add_argument("--variants", nargs="+", default=None, help="variants to run (default: every registered one)")
    p.add_argument("--set", action="append", metavar="VARIANT.PARAM=VALUE", help="override a variant parameter")
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: CPU count; 0: run in this process, unprotected)")
    p.add_argument("--memory-limit-gb", type=float, default=MEMORY_LIMIT_GB,
                   help=f"memory limit of each local worker, GiB (default {MEMORY_LIMIT_GB:g}; 0: none)")
    p.add_argument("--timeout", type=float, default=TIMEOUT_S,
                   help=f"stop a local worker silent this long on one variant, s (default {TIMEOUT_S:g}; 0: never)")
    p.add_argument("--scheduler", default=None, help="Dask scheduler address (tcp://host:port) to run the cases on")
    if db_default is not None:
        p.add_argument("--db", default=db_default, help=f"results database (default {db_default})")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tlsbench", description="Benchmark harness of the TLS laboratory.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="run a suite and store the results")
    p.add_argument("--suite", required=True, help=f"built-in suite ({', '.join(suite_names())}) or suite file")
    _add_execution(p)
    p.add_argument("-o", "--output", required=True, help="directory for report.html and report.json")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--new", action="store_true", help="start a new run even if an unfinished one matches")
    group.add_argument("--resume", metavar="RUN", help="continue this run (id, prefix or latest)")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("report", help="report a stored run (HTML page or JSON document)")
    p.add_argument("run", help="run id, unique id prefix, or 'latest'")
    p.add_argument("--db", default="results.sqlite", help="results database (default results.sqlite)")
    p.add_argument("-o", "--output", default=None,
                   help="write the report here: the JSON document for a .json path, else the HTML page")
    p.add_argument("--json", action="store_true", help="print the JSON report")
    p.add_argument("--no-before-after", action="store_true", help="skip the re-simulated before/after figure")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("compare", help="flag regressions of RUN_B against RUN_A (exit 1 if any)")
    p.add_argument("run_a")
    p.add_argument("run_b")
    p.add_argument("--db", default="results.sqlite", help="results database (default results.sqlite)")
    p.add_argument("--z", type=float, default=3.0, help="standard errors a change must exceed (default 3)")
    p.add_argument("--changes", action="store_true", help="show only metrics that changed")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("sweep", help="stress sweep: ROP, range noise and intensity against one parameter")
    p.add_argument("kind", choices=list(sweeps.SWEEPS))
    p.add_argument("--scene", default="single-leaf", help="scene generator (default single-leaf)")
    p.add_argument("--values", nargs="+", type=float, default=None, help="values of the swept parameter")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="fixed scene-generator parameter")
    p.add_argument("--scanner", action="append", metavar="KEY=VALUE", help="fixed scanner override")
    p.add_argument("--repeats", type=int, default=1, help="cases per value (different seeds)")
    _add_execution(p)
    p.add_argument("-o", "--output", default="sweeps", help="directory for the table and plot (default sweeps)")
    p.set_defaults(func=cmd_sweep, variants_default=["raw"])

    p = sub.add_parser("main", help="the main job: suite, variants, sweeps, store, report, headline table")
    p.add_argument("-o", "--output", default="bench-out", help="output directory (default bench-out)")
    p.add_argument("--suite", default=MAIN_SUITE, help=f"suite (default {MAIN_SUITE})")
    _add_execution(p, db_default=None)
    p.add_argument("--db", default=None, help="results database (default OUTPUT/results.sqlite)")
    p.set_defaults(func=cmd_main)

    p = sub.add_parser("baseline", help="the committed baseline of a suite (benchmarks/baseline/SUITE.json)")
    p = p.add_subparsers(dest="action", required=True, metavar="ACTION").add_parser(
        "update", help="rewrite the baseline from a new run of the suite (or a stored one, --run)")
    _add_baseline_options(p)
    p.set_defaults(func=cmd_baseline_update)

    p = sub.add_parser("check", help="run the suite and compare it with its baseline (exit 1 on a regression)")
    _add_baseline_options(p)
    p.add_argument("--timing-band", type=float, default=TIMING_BAND,
                   help=f"factor by which a runtime (per trace time and in seconds) may move before a "
                        f"warning (default {TIMING_BAND:g})")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("history", help="a metric across the commits of the stored runs (table and PNG chart)")
    p.add_argument("metric", help="summary metric, e.g. rop_reduction, area_rel_err_median, runtime_s")
    p.add_argument("--variant", default=None, help="only this variant (default: all)")
    p.add_argument("--suite", default=MAIN_SUITE, help=f"suite name (default {MAIN_SUITE})")
    p.add_argument("--case", default=None, help="the metric on this case alone (default: over the suite)")
    p.add_argument("--db", default="results.sqlite", help="results database (default results.sqlite)")
    p.add_argument("-o", "--output", default=None, help="chart (default history-METRIC[-VARIANT].png)")
    p.set_defaults(func=cmd_history)

    add_experiment_parsers(sub)
    add_reproduce_parser(sub)

    p = sub.add_parser("budget", help="where the outliers a leaf variant leaves on one case come from (by truth)")
    p.add_argument("--suite", required=True, help=f"built-in suite ({', '.join(suite_names())}) or suite file")
    p.add_argument("--case", default=None, help="case name (default: the suite's only case)")
    p.add_argument("--variant", default="fused", help="leaf variant (default fused)")
    p.add_argument("--threshold", choices=("auto", "1cm"), default="auto",
                   help="outlier threshold: auto = 3 sigma of the leaf's range noise (default), or 1cm")
    p.add_argument("--top", type=int, default=12, help="largest groups of outliers left to list (default 12)")
    p.add_argument("--json", action="store_true", help="print the budget as JSON")
    p.set_defaults(func=cmd_budget)

    p = sub.add_parser("list", help="list suites, variants, scene generators and sweeps")
    p.set_defaults(func=cmd_list)
    return parser


def _add_baseline_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--suite", default=MAIN_SUITE, help=f"built-in suite or suite file (default {MAIN_SUITE})")
    _add_execution(p)
    p.add_argument("--run", default=None, help="use this stored run of --db (id, prefix, latest) instead of running")
    p.add_argument("--baseline", default=None, help="baseline file (default benchmarks/baseline/SUITE.json)")


def _baseline_run(args, store: Store) -> str:
    """The run a baseline command works on: ``--run`` of the store, or a new complete run of the suite."""
    if args.run:
        return store.resolve(args.run)
    return _run_suite(load_suite(args.suite), args, store).run_id


def _run_suite(suite, args, store: Store, resume=True, notes=None):
    variants = registry.resolve(args.variants, _overrides(args.set))
    outcome = execute(suite, variants, store, workers=args.workers, scheduler=args.scheduler, resume=resume,
                      progress=not args.quiet, notes=notes, memory_limit_gb=args.memory_limit_gb,
                      timeout_s=args.timeout or None)
    state = "resumed" if outcome.resumed else "new"
    print(f"run {outcome.run_id} ({state}): {outcome.cases_run} case(s) run, {outcome.cases_skipped} already done, "
          f"{outcome.elapsed_s:.1f} s", file=sys.stderr)
    return outcome


def _write_reports(store: Store, run_id: str, outdir) -> tuple[Path, Path]:
    from benchmarks.report import report_document, write_html

    outdir = Path(outdir)
    html_path = write_html(store, run_id, outdir / "report.html")
    json_path = outdir / "report.json"
    json_path.write_text(json.dumps(report_document(store, run_id), indent=2))
    return html_path, json_path


def _print_headline(store: Store, run_id: str) -> None:
    info = store.run_info(run_id)
    rows = store.results(run_id)
    table = summary.summarize(rows, info["suite"])
    print(f"suite {info['suite']}, run {run_id}")
    print(summary.headline_table(table))
    print(summary.goal_status(table))
    leaves = summary.leaf_printout(rows)
    if leaves:
        print(leaves)


def _failures(store: Store, run_ids: list[str]) -> int:
    """Say how many results of the runs failed, with the first error; 1 if any failed, else 0."""
    failed = [row for run_id in run_ids for row in store.results(run_id) if row.get("error")]
    if failed:
        first = failed[0]
        print(f"{len(failed)} result(s) failed; the first: case {first['case_name']!r}, variant {first['variant']!r}: "
              f"{first['error']}", file=sys.stderr)
    return 1 if failed else 0


def cmd_run(args) -> int:
    suite = load_suite(args.suite)
    with Store(args.db) as store:
        resume = False if args.new else args.resume or True
        outcome = _run_suite(suite, args, store, resume=resume)
        html_path, json_path = _write_reports(store, outcome.run_id, args.output)
        _print_headline(store, outcome.run_id)
        status = _failures(store, [outcome.run_id])
    print(f"report: {html_path} and {json_path}")
    return status


def cmd_report(args) -> int:
    from benchmarks.report import report_document, write_html

    with Store(args.db, create=False) as store:
        run_id = store.resolve(args.run)
        if args.output and Path(args.output).suffix.lower() == ".json":
            Path(args.output).write_text(json.dumps(report_document(store, run_id), indent=2))
            print(f"report: {args.output}", file=sys.stderr)
        elif args.output:
            path = write_html(store, run_id, args.output, before_after=not args.no_before_after)
            print(f"report: {path}", file=sys.stderr)
        if args.json:
            print(json.dumps(report_document(store, run_id), indent=2))
        elif not args.output:
            _print_headline(store, run_id)
    return 0


def cmd_compare(args) -> int:
    from benchmarks.compare import compare_runs, format_comparison

    with Store(args.db, create=False) as store:
        run_a, run_b = store.resolve(args.run_a), store.resolve(args.run_b)
        entries = compare_runs(store.results(run_a), store.results(run_b), z=args.z)
    print(f"B = {run_b} against A = {run_a}")
    print(format_comparison(entries, only_changes=args.changes))
    regressions = [e for e in entries if e["verdict"] == "regression"]
    print(f"{len(regressions)} regression(s)")
    return 1 if regressions else 0


def _sweep(suite, args, store: Store):
    """Run a sweep's suite; return its run id and table."""
    kind = sweeps.sweep_of(suite.name)
    outcome = _run_suite(suite, args, store)
    table = sweeps.sweep_table(store.results(outcome.run_id), kind)
    return outcome.run_id, table


def cmd_sweep(args) -> int:
    args.variants = args.variants or args.variants_default
    with Store(args.db) as store:
        suite = sweeps.sweep_suite(args.kind, args.scene, args.values, _assignments(args.param, "--param"),
                                   _assignments(args.scanner, "--scanner"), args.repeats)
        run_id, table = _sweep(suite, args, store)
        status = _failures(store, [run_id])
    csv_path, png_path = sweeps.write_sweep(table, args.kind, args.output)
    print(f"sweep {args.kind}, run {run_id}")
    print(sweeps.format_table(table))
    print(f"table: {csv_path}  plot: {png_path}")
    return status


def cmd_main(args) -> int:
    start = time.perf_counter()
    outdir = Path(args.output)
    suite = load_suite(args.suite)
    with Store(args.db or outdir / "results.sqlite") as store:
        outcome = _run_suite(suite, args, store)
        sweep_args = argparse.Namespace(**{**vars(args), "variants": [v.name for v in registry.resolve(args.variants)
                                                                      if v.family in ("raw", "filter")]})
        sweep_ids = []
        for kind in MAIN_SWEEPS:
            run_id, table = _sweep(sweeps.sweep_suite(kind), sweep_args, store)
            sweeps.write_sweep(table, kind, outdir)
            sweep_ids.append(run_id)
        store.set_notes(outcome.run_id, {"sweeps": sweep_ids})
        html_path, json_path = _write_reports(store, outcome.run_id, outdir)
        print()
        _print_headline(store, outcome.run_id)
        status = _failures(store, [outcome.run_id, *sweep_ids])
    print(f"report: {html_path} and {json_path}; sweeps: {', '.join(MAIN_SWEEPS)} in {outdir}")
    print(f"main job finished in {time.perf_counter() - start:.0f} s")
    return status


def cmd_baseline_update(args) -> int:
    with Store(args.db, create=not args.run) as store:
        run_id = _baseline_run(args, store)
        document = baseline.baseline_of_run(store, run_id)
    path = baseline.baseline_path(document["suite"], args.baseline)
    if path.is_file():
        old = baseline.load_baseline(path, document["suite"])
        changes = baseline.compare_to_baseline(old, document, document["variants"])
        for change in changes:
            print(f"{change.verdict}: {change.describe()}")
        print(f"{len(changes)} metric value(s) moved beyond the tolerances since the previous baseline "
              f"(commit {old['commit']})")
    baseline.write_baseline(document, path)
    print(f"baseline of suite {document['suite']} written to {path} from run {run_id} (commit {document['commit']})")
    return 0


def cmd_check(args) -> int:
    def load(suite: str) -> dict:
        return baseline.load_baseline(baseline.baseline_path(suite, args.baseline), suite)

    baseline.valid_band(args.timing_band)  # refuse bad options and a missing baseline before running anything
    old = None if args.run else load(load_suite(args.suite).name)
    with Store(args.db, create=not args.run) as store:
        current = baseline.run_document(store, _baseline_run(args, store))
    old = old or load(current["suite"])
    variants = current["variants"] if args.variants else old["variants"]
    text, passed = baseline.format_check(old, current, baseline.compare_to_baseline(old, current, variants),
                                         args.timing_band)
    print(text)
    return 0 if passed else 1


def cmd_history(args) -> int:
    from benchmarks.history import format_history, metric_history, plot_history

    with Store(args.db, create=False) as store:
        points = metric_history(store, args.metric, args.suite, args.variant, args.case)
    print(format_history(points, args.metric))
    path = Path(args.output or f"history-{args.metric}{'-' + args.variant if args.variant else ''}.png")
    path.parent.mkdir(parents=True, exist_ok=True)
    plot_history(points, args.metric, f"{args.metric} of suite {args.suite}" + (f", case {args.case}" if args.case
                                                                               else "")).savefig(path, dpi=100)
    print(f"chart: {path}")
    return 0


def cmd_budget(args) -> int:
    from benchmarks.budget import case_budget, format_budget

    cases = load_suite(args.suite).cases
    names = [case.name for case in cases]
    if args.case is None and len(cases) != 1:
        raise BenchError(f"the suite has {len(cases)} cases; name one with --case: {', '.join(names)}")
    if args.case is not None and args.case not in names:
        raise BenchError(f"no case {args.case!r} in the suite; cases: {', '.join(names)}")
    case = cases[0] if args.case is None else cases[names.index(args.case)]
    budget = case_budget(case, args.variant, args.threshold)
    print(json.dumps(budget, indent=1) if args.json else format_budget(budget, args.top))
    return 0


def cmd_list(args) -> int:
    print("suites:", ", ".join(suite_names()))
    print("variants:")
    for name in registry.variant_names():
        variant = registry.get_variant(name)
        params = json.dumps(variant.params)
        print(f"  {name:12s} {variant.family:9s} {variant.description}" + (f"  {params}" if len(params) < 100 else ""))
    print("scene generators:")
    for name, text in describe_generators().items():
        print(f"  {name:14s} {text}")
    print("sweeps:", ", ".join(f"{k} ({v.key})" for k, v in sweeps.SWEEPS.items()))
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_main(build_parser(), argv if argv is not None else sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())
