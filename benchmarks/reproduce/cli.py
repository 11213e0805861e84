"""``tlsbench reproduce [NAME ...]``: run reproduction experiments, print, write and store them.

Each experiment prints the published values and ours side by side with a
verdict per row and writes ``NAME.csv`` and ``NAME.png`` under the output
directory; all of them go to ``reproduction.html`` there and to one run of
the results store. The last line reads ``N/M rows within tolerance``.
With ``--scheduler ADDRESS`` each experiment runs as one task on that Dask
cluster; its rows come back as plain fields and are printed, written and
stored the same way.
"""

from __future__ import annotations

import importlib
import sys
import time
import traceback
from pathlib import Path

from benchmarks.errors import BenchError
from benchmarks.reproduce.core import EXPERIMENTS, Outcome, Row, count_within, select
from benchmarks.reproduce.output import (figure_png, format_rows, store_outcomes, summary_line, summary_table,
                                         write_csv, write_images, write_png)
from benchmarks.store import Store

#: Modules that register experiments, in the order of the page.
MODULES = ("benchmarks.reproduce.sensors2011", "benchmarks.reproduce.thesis_ch5", "benchmarks.reproduce.thesis_ch7",
           "benchmarks.reproduce.thesis_ch2",
           "benchmarks.reproduce.woody_papers")


def load_experiments() -> dict:
    """Import every module of :data:`MODULES` (registering their experiments); returns the registry."""
    for name in MODULES:
        importlib.import_module(name)
    return EXPERIMENTS


def add_parser(sub) -> None:
    """Register ``reproduce`` with the ``tlsbench`` sub-commands."""
    p = sub.add_parser("reproduce", help="reproduce the sources' published tables and figures, with verdicts",
                       description="Run the registered reproduction experiments (all when no NAME is given; "
                                   "NAME may end in '*'), print published values and ours side by side, write "
                                   "CSV, PNG and reproduction.html, and store the rows.")
    p.add_argument("names", nargs="*", metavar="NAME", help="experiments to run (default: all)")
    p.add_argument("--list", action="store_true", help="list the registered experiments and exit")
    p.add_argument("--quick", action="store_true",
                   help="tiny versions (tests, make bench); heavy experiments only when named one by one")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulations (default 0)")
    p.add_argument("-o", "--output", default="reproduction", help="output directory (default reproduction)")
    p.add_argument("--db", default="reproduction.sqlite",
                   help="results database (default reproduction.sqlite: a store of its own, so that the suites' "
                        "'latest' run stays a suite run; compare two runs with tlsbench compare A B --db ...)")
    p.add_argument("--no-store", action="store_true", help="do not write the rows to the results store")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler address (tcp://host:port): each experiment runs as one task there")
    p.set_defaults(func=run)


def run_one(name: str, quick: bool, seed: int) -> dict:
    """Run one registered experiment, catching its failure (the unit of work sent to Dask).

    Parameters
    ----------
    name : str
        Registered experiment name.
    quick : bool
        Run the tiny version.
    seed : int
        Seed of the simulations.

    Returns
    -------
    dict
        ``rows`` (the rows' fields, plain values), ``seconds``, ``error`` (empty when it ran) and ``images``
        (the experiment's extra figures as base64 PNG by name).
    """
    experiment = load_experiments()[name]
    start = time.perf_counter()
    rows, error, images = [], "", {}
    try:
        result = experiment.run(quick, seed)
        result, figures = result if isinstance(result, tuple) else (result, {})
        rows = [{k: v for k, v in r.as_dict().items() if k != "verdict"} for r in result]
        images = {key: figure_png(figure) for key, figure in figures.items()}
    except Exception as exc:  # one failing experiment must not hide the others' rows
        error = f"{type(exc).__name__}: {exc}"
        traceback.print_exc(file=sys.stderr)
    return {"rows": rows, "seconds": time.perf_counter() - start, "error": error, "images": images}


def _dispatch_dask(names: list[str], quick: bool, seed: int, address: str):
    """Yield ``(name, run_one result)`` as the experiments finish on the Dask cluster at ``address``."""
    from distributed import Client, as_completed

    try:
        client = Client(address, timeout="30s")
    except (OSError, TimeoutError) as exc:
        raise BenchError(f"cannot reach the Dask scheduler at {address!r} ({exc})") from None
    with client:
        futures = {client.submit(run_one, name, quick, seed, pure=False): name for name in names}
        try:
            for future in as_completed(futures):
                try:
                    yield futures[future], future.result()
                except Exception as exc:  # noqa: BLE001 - e.g. a lost worker: the experiment is reported failed
                    yield futures[future], {"rows": [], "seconds": 0.0, "error": f"Dask: {type(exc).__name__}: {exc}"}
        finally:
            client.cancel(list(futures))


def run_experiments(names: list[str] | None, quick: bool, seed: int, echo=print,
                    scheduler: str | None = None) -> list[Outcome]:
    """Run the named experiments, printing each table; an experiment that fails is reported, not raised.

    Parameters
    ----------
    names : list of str or None
        Experiment names (all when empty).
    quick : bool
        Run the tiny versions.
    seed : int
        Seed of the simulations.
    echo : callable
        Where the tables go (``print``).
    scheduler : str or None
        Dask scheduler address: run each experiment as a task there (tables
        printed as they finish; outcomes kept in registration order).

    Returns
    -------
    list of Outcome
        One per experiment, in registration order.
    """
    load_experiments()
    chosen = [e.name for e in select(names, quick)]
    results = (_dispatch_dask(chosen, quick, seed, scheduler) if scheduler
               else ((name, run_one(name, quick, seed)) for name in chosen))
    outcomes = {}
    for name, result in results:
        outcome = Outcome(EXPERIMENTS[name], [Row(**row) for row in result["rows"]], result["seconds"], result["error"],
                          result.get("images", {}))
        within, compared = count_within(outcome.rows)
        echo(f"\n== {name}: {outcome.experiment.title} ({within}/{compared} within, {outcome.seconds:.1f} s)")
        echo(format_rows(outcome.rows) if outcome.rows else f"failed: {outcome.error}")
        outcomes[name] = outcome
    return [outcomes[name] for name in chosen]


def run(args) -> int:
    """The command (see the module docstring); exit status 1 when an experiment failed."""
    if args.list:
        for experiment in load_experiments().values():
            print(f"{experiment.name:24s} {'heavy ' if experiment.heavy else '      '}{experiment.title}")
        return 0
    from benchmarks.reproduce.page import write_page  # imports benchmarks.report and its modules: only when run

    outcomes = run_experiments(args.names, args.quick, args.seed, scheduler=args.scheduler)
    out = Path(args.output)
    for outcome in outcomes:
        if outcome.rows:
            write_csv(outcome.rows, out / f"{outcome.experiment.name}.csv")
            write_png(outcome.experiment, outcome.rows, out / f"{outcome.experiment.name}.png")
        write_images(outcome.experiment.name, outcome.images, out)
    ran = {o.experiment.name for o in outcomes}
    left_out = [e.name for e in select(args.names, False) if e.name not in ran] if args.quick else []
    command = "tlsbench reproduce " + " ".join(sys.argv[2:] if sys.argv[1:2] == ["reproduce"] else [])
    page = write_page(outcomes, out / "reproduction.html", command.strip(), left_out)
    if not args.no_store:
        with Store(args.db) as store:
            run_id = store_outcomes(store, outcomes, args.quick, args.seed)
        print(f"stored as run {run_id} in {args.db}")
    print(f"CSV and PNG per experiment and {page} written\n")
    print(summary_table(outcomes, left_out))
    print(summary_line([r for o in outcomes for r in o.rows]))
    return 1 if any(o.error for o in outcomes) else 0
