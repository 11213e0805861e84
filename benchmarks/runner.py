"""Running a suite: cases in parallel on this machine or on a Dask cluster, results into the store.

:func:`case_rows` is the unit of work: it rebuilds a case's scene,
simulates the scan (deterministic from the case seed), runs each requested
variant on every target leaf (or once on the whole scan, for variants of
scope ``scan``) and scores it. It takes and returns JSON-ready
data, so the same function runs inline, in local worker processes or on Dask
workers (:func:`run_case`).

:func:`execute` sends the cases that are not yet in the store for a run
(to the local pool of :mod:`benchmarks.pool`, inline, or to Dask), writes
each result row as soon as it arrives, and shows a progress bar. A stopped
run resumes from the store: finished (case, variant) pairs are never redone.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from tqdm.auto import tqdm

from benchmarks import heightfields, scoring
from benchmarks.errors import BenchError
from benchmarks.generators import build_scene
from benchmarks.pool import run_local
from benchmarks.registry import Variant, get_variant
from benchmarks.store import Store, git_commit
from benchmarks.suite import Case, Suite

_CLEAR_REFS = Path("/proc/self/clear_refs")


def _rss_mb(field: str) -> float | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def _reset_peak_rss() -> bool:
    try:
        _CLEAR_REFS.write_text("5")
        return True
    except OSError:
        return False


def measured(func, *args):
    """Call ``func(*args)``; return its result, wall time (s) and peak memory above the start (MB).

    Peak memory is the growth of the process's resident-set high-water mark
    (Linux ``VmHWM``, reset through ``/proc/self/clear_refs`` before the
    call); it is ``None`` where the kernel does not offer that. It counts
    every allocation of the process (numpy, Dr.Jit), so it is meaningful
    when one case runs per process (local pools, Dask workers with one
    thread).

    Parameters
    ----------
    func : callable
        Function to call.
    *args
        Its positional arguments.

    Returns
    -------
    result : object
        What ``func`` returned.
    elapsed : float
        Wall time, s.
    peak : float or None
        Peak resident memory above the start, MB; ``None`` where not measurable.
    """
    start_rss = _rss_mb("VmRSS") if _reset_peak_rss() else None
    start = time.perf_counter()
    result = func(*args)
    elapsed = time.perf_counter() - start
    peak = _rss_mb("VmHWM") if start_rss is not None else None
    return result, elapsed, None if peak is None else max(peak - start_rss, 0.0)


def variant_specs(variants: list[Variant]) -> list[dict]:
    """JSON-ready ``{name, family, params}`` of each variant (what workers receive)."""
    return [{"name": v.name, "family": v.family, "params": v.params} for v in variants]


def scan_setup(case: Case, scene):
    """The scanner setup of a case: the case's ``scanner`` entries override the scene's scanner section
    (window, pose) and the scanner model's fields; a case's ``step_deg`` also replaces the step of the scene's
    window (built-in scenes give their window a step, which would otherwise win).

    Parameters
    ----------
    case : Case
        The case.
    scene : Scene
        Its scene (:func:`benchmarks.generators.build_scene`).

    Returns
    -------
    tlssim.simulate.ScanSetup
    """
    from tlssim.simulate import setup_from_section

    section = {**scene.scanner, **case.scanner}
    if "step_deg" in case.scanner and "window" not in case.scanner and "window" in section:
        section["window"] = {**section["window"], "step_deg": case.scanner["step_deg"]}
    return setup_from_section(section)


def simulate_case(case: Case):
    """Rebuild a case's scene and simulate its scan (deterministic from the case; setup: :func:`scan_setup`).

    Returns
    -------
    scene : Scene
    scan : tlssim.Scan
    """
    from tlssim.simulate import simulate

    scene = build_scene(case.scene)
    return scene, simulate(scene, scan_setup(case, scene), seed=case.seed, progress=False)


def case_rows(case: dict, variants: list[dict]):
    """Simulate one case and score every variant on its target leaves, yielding one row per variant.

    Parameters
    ----------
    case : dict
        :meth:`benchmarks.suite.Case.to_dict` of the case.
    variants : list of dict
        :func:`variant_specs` of the variants to run (looked up in the
        registry of the process that runs the case).

    Yields
    ------
    dict
        A row for :meth:`benchmarks.store.Store.add_results` as soon as the
        variant is scored; a variant that fails on the case gets a row with
        its ``error``.
    """
    from tlssim.simulate import BYTES_PER_PULSE, simulate

    case = Case.from_dict(case)
    if heightfields.is_heightfield(case.scene):
        yield from _heightfield_rows(case, variants)
        return
    try:
        scene, build_s, _ = measured(build_scene, case.scene)
        setup = scan_setup(case, scene)
        if setup.window.shape[0] * setup.window.shape[1] * BYTES_PER_PULSE > TILED_SCAN_BYTES:
            yield from _tiled_rows(case, scene, setup, build_s, variants)
            return
        scan, simulate_s, _ = measured(lambda: simulate(scene, setup, seed=case.seed, progress=False))
        simulate_s += build_s
        leaves = scoring.prepare_leaves(scene, scan, None if case.targets is None else list(case.targets))
        wood = scoring.prepare_wood(scene, scan)
    except Exception as exc:  # noqa: BLE001 - a broken case is recorded, not fatal to the run
        for spec in variants:
            yield error_row(case, spec, _message(exc))
        return
    for spec in variants:
        try:
            variant = case_variant(case, spec)
            targets = wood if variant.target == "wood" else leaves
            if variant.prepare is not None and targets:
                variant.prepare(scan)
            if variant.scope == "scan" and targets:
                cpu = time.process_time()
                output, runtime, peak = measured(variant, scan, scoring.target_labels(scan.shape, leaves))
                cpu = time.process_time() - cpu
                scores, counts = scoring.score_scan(leaves, output, scene, scan)
                counts["cpu_s"] = cpu
                pulses = scan.shape[0] * scan.shape[1]
            else:
                scores, runtime, peaks, pulses = [], 0.0, [], 0
                score = scoring.score_wood if variant.target == "wood" else scoring.score_leaf
                for target in targets:
                    output, elapsed, peak = measured(variant, target.scan, target.mask)
                    runtime += elapsed
                    peaks.append(peak)
                    pulses += target.scan.shape[0] * target.scan.shape[1]
                    scores.append(score(target, output))
                peak = None if not peaks or any(p is None for p in peaks) else max(peaks)
                counts = {}
            counts = {**counts, "n_pulses": pulses}
            yield _row(case, spec, {"targets": scores, "case": counts}, runtime, peak, simulate_s, None)
        except Exception as exc:  # noqa: BLE001 - a failing variant is recorded, the others still run
            yield _row(case, spec, {"targets": []}, None, None, simulate_s, _message(exc))


#: A case whose scan would hold more than this in memory (:data:`~tlssim.simulate.BYTES_PER_PULSE` per pulse) is
#: simulated into tiles on disk and scored window by window (:func:`_tiled_rows`), bytes.
TILED_SCAN_BYTES = 2 * 1024**3
#: Memory of one scoring window of a tiled case (the scan's columns, the truth, the variant's outputs), bytes, at
#: :data:`leafsfs.tiled.RECONSTRUCT_BYTES_PER_PULSE` per pulse (imports and scan included): windows of at most
#: 18 M pulses, within issue 16's 8 GB. Smaller windows repeat their margins' pulses and cut leaves near the
#: borders: the orchard row's 3334 x 3334 window at 0.018 deg (margins of about 440 columns) is one window of
#: 11.1 M pulses at this budget (peak 3,120 MB), 2 windows of 14.0 M in all at 3e9.
TILED_WINDOW_BYTES = 6e9


def tiles_root() -> Path:
    """Where the tiled scans of large cases are kept: ``$TLSBENCH_TILES``, else ``<tmp>/tlsbench-tiles``.

    A scan is written once per case description and reused (its tiles check
    by SHA-256; an interrupted one resumes).
    """
    import tempfile

    return Path(os.environ.get("TLSBENCH_TILES") or Path(tempfile.gettempdir()) / "tlsbench-tiles")


def _tiled_rows(case: Case, scene, setup, build_s: float, variants: list[dict]):
    """Rows of a case too large for memory: simulated into tiles, scored window by window.

    The scan's columns are cut into cores; each core is scored in a window
    widened by the columns the largest leaf spans at its nearest pulses
    (:func:`leafsfs.tiled.margin_columns`), so a leaf cut by a core border
    lies whole in the window of the core that holds its centroid column,
    and is scored there only. Variants of scope ``scan`` run on every window;
    of their regions only those whose centroid lies in the core count
    (a leaf matched to a region centred across the border counts as not
    found: a small undercount near the borders). Counts are summed over the
    windows (``cpu_s``: the variant's CPU time, ``window_pulses``: the
    pulses it was given); ``runtime_s`` sums the variant's time over the
    windows and ``peak_mem_mb`` is the largest window's. Wood variants are
    not scored on tiled cases.
    """
    import numpy as np

    from leafsfs.tiled import LEAF_SIZE_M, SIZING_COLS, core_columns, margin_columns
    from tlssim.simulate import simulate_tiled

    try:
        digest = hashlib.sha256(json.dumps(case.to_dict(), sort_keys=True).encode()).hexdigest()[:16]
        tiled, simulate_s, _ = measured(lambda: simulate_tiled(
            scene, setup, tiles_root() / f"{case.name}-{digest}", seed=case.seed, progress=False))
        simulate_s += build_s
    except Exception as exc:  # noqa: BLE001 - a broken case is recorded, not fatal to the run
        for spec in variants:
            yield error_row(case, spec, _message(exc))
        return
    rows, cols = tiled.shape
    # the cores are sized from a fixed count of columns, not the first tile: the scores do not depend on the tiling
    first = tiled.load_columns(0, min(cols, SIZING_COLS))
    core = core_columns(rows, TILED_WINDOW_BYTES, margin_columns(first, LEAF_SIZE_M, cols))
    del first
    chosen = {spec["name"]: case_variant(case, spec) for spec in variants}
    acc = {name: {"scores": [], "counts": {}, "runtime": 0.0, "peaks": [], "pulses": 0, "error": None}
           for name in chosen}
    for name, variant in chosen.items():
        if variant.target == "wood":
            acc[name]["error"] = "BenchError: wood variants are not scored on tiled cases"
    for c0 in range(0, cols, core):
        c1 = min(cols, c0 + core)
        margin = margin_columns(tiled.load_columns(c0, c1), LEAF_SIZE_M, cols)
        w0, w1 = max(0, c0 - margin), min(cols, c1 + margin)
        scan = tiled.load_columns(w0, w1)
        try:
            window_leaves = scoring.prepare_leaves(scene, scan, None if case.targets is None else list(case.targets))
        except Exception as exc:  # noqa: BLE001 - recorded on every variant
            for state in acc.values():
                state["error"] = state["error"] or _message(exc)
            continue
        leaves = [leaf for leaf in window_leaves if c0 <= np.mean(leaf.own_pixels()[1]) + w0 < c1]
        for name, variant in chosen.items():
            state = acc[name]
            if state["error"] is not None or not leaves:
                continue
            try:
                if variant.prepare is not None:
                    variant.prepare(scan)
                if variant.scope == "scan":
                    cpu = time.process_time()
                    output, runtime, peak = measured(variant, scan, scoring.target_labels(scan.shape, window_leaves))
                    cpu = time.process_time() - cpu
                    output = _core_regions(output, w0, c0, c1)
                    scores, counts = scoring.score_scan(leaves, output, scene, scan)
                    counts.update(cpu_s=cpu, window_pulses=scan.shape[0] * scan.shape[1])
                    state["peaks"].append(peak)
                    state["pulses"] = rows * cols  # every pulse is in one core
                else:
                    scores, runtime, counts = [], 0.0, {}
                    for target in leaves:
                        out, elapsed, peak = measured(variant, target.scan, target.mask)
                        runtime += elapsed
                        state["peaks"].append(peak)
                        state["pulses"] += target.scan.shape[0] * target.scan.shape[1]
                        scores.append(scoring.score_leaf(target, out))
                state["scores"] += scores
                state["runtime"] += runtime
                for key, value in counts.items():
                    state["counts"][key] = state["counts"].get(key, 0) + value
            except Exception as exc:  # noqa: BLE001 - a failing variant is recorded, the others still run
                state["error"] = _message(exc)
        del scan
    for spec in variants:
        state = acc[spec["name"]]
        if state["error"] is not None:
            yield _row(case, spec, {"targets": []}, None, None, simulate_s, state["error"])
            continue
        peaks = state["peaks"]
        found = scoring.found_counts(state["scores"]) if chosen[spec["name"]].scope == "scan" else {}
        counts = {**state["counts"], **found, "n_pulses": state["pulses"], "tiled_core_cols": core}
        peak = None if not peaks or any(p is None for p in peaks) else max(peaks)
        yield _row(case, spec, {"targets": state["scores"], "case": counts}, state["runtime"], peak, simulate_s,
                   None)


def _core_regions(output, w0: int, c0: int, c1: int):
    """A scan-scope output keeping only the regions whose centroid column lies in the core ``c0:c1``."""
    import dataclasses

    import numpy as np

    if output.labels is None or output.regions is None:
        return output
    labels = np.asarray(output.labels)
    n = int(labels.max(initial=0)) + 1
    count = np.bincount(labels.ravel(), minlength=n)
    column = np.broadcast_to(np.arange(labels.shape[1]) + w0, labels.shape)
    centroid = np.bincount(labels.ravel(), weights=column.ravel(), minlength=n) / np.maximum(count, 1)
    keep = (centroid >= c0) & (centroid < c1)
    keep[0] = False
    regions = {label: traits for label, traits in output.regions.items() if int(label) < n and keep[int(label)]}
    return dataclasses.replace(output, labels=np.where(keep[labels], labels, 0), regions=regions)


def case_variant(case: Case, spec: dict) -> Variant:
    """The variant of ``spec`` with the case's own parameters for it applied (by family, then by name).

    Parameters
    ----------
    case : Case
        The case, with per-family and per-variant parameter overrides.
    spec : dict
        Variant specification (``name``, ``params``).

    Returns
    -------
    Variant
        The variant with its parameters (in their own units) applied.
    """
    variant = get_variant(spec["name"]).with_params(**spec["params"])
    return variant.with_params(**case.params.get(variant.family, {})).with_params(**case.params.get(variant.name, {}))


def _heightfield_rows(case: Case, variants: list[dict]):
    """Rows of a height-field case (:mod:`benchmarks.heightfields`): no scan, the height image is reconstructed."""
    try:
        sampled, sample_s, _ = measured(heightfields.sample, case.scene, case.seed)
    except Exception as exc:  # noqa: BLE001 - a broken case is recorded, not fatal to the run
        for spec in variants:
            yield error_row(case, spec, _message(exc))
        return
    for spec in variants:
        try:
            variant = case_variant(case, spec)
            result, runtime, peak = measured(variant.reconstruct_heights, sampled)
            scores = scoring.json_ready(heightfields.score_heights(case.scene, sampled, result))
            yield _row(case, spec, {"targets": [scores]}, runtime, peak, sample_s, None)
        except Exception as exc:  # noqa: BLE001 - a failing variant is recorded, the others still run
            yield _row(case, spec, {"targets": []}, None, None, sample_s, _message(exc))


def applies(variant: Variant, case: Case) -> bool:
    """Whether a variant runs on a case: height-field cases need a method that reconstructs height fields.

    Parameters
    ----------
    variant : Variant
        The method variant.
    case : Case
        The benchmark case.

    Returns
    -------
    bool
        Whether the variant runs on the case.
    """
    return variant.heights is not None or not heightfields.is_heightfield(case.scene)


def run_case(case: dict, variants: list[dict]) -> list[dict]:
    """All rows of :func:`case_rows` at once (the unit of work sent to Dask).

    Parameters
    ----------
    case : dict
        :meth:`benchmarks.suite.Case.to_dict` of the case.
    variants : list of dict
        :func:`variant_specs` of the variants to run.

    Returns
    -------
    list of dict
        Result rows, one per variant (metrics in the units of their names).
    """
    return list(case_rows(case, variants))


def error_row(case: Case, spec: dict, message: str) -> dict:
    """The row of a variant that could not be run on a case.

    Parameters
    ----------
    case : Case
        The case.
    spec : dict
        Variant specification (``name``, ``params``).
    message : str
        Why the variant could not run (one line).

    Returns
    -------
    dict
        A result row with no targets and the error message.
    """
    return _row(case, spec, {"targets": []}, None, None, None, message)


def _failed_row(case: dict, spec: dict, message: str) -> dict:
    """:func:`error_row` of a case given as :meth:`~benchmarks.suite.Case.to_dict` (what the pool holds)."""
    return error_row(Case.from_dict(case), spec, message)


def _warm_up() -> None:
    """Compile the simulator's kernels once per worker, so that no case pays for it."""
    simulate_case(Case("warm-up", {"builtin": "knife-edge"}, {"window": {"theta_deg": [0, 0], "psi_deg": [90, 90]}}, 0))


def _message(exc: BaseException) -> str:
    """``Type: message``, and where it was raised unless it is a user-facing error (ValueError)."""
    text = f"{type(exc).__name__}: {exc}"
    if isinstance(exc, ValueError) or exc.__traceback__ is None:
        return text
    frame = traceback.extract_tb(exc.__traceback__)[-1]
    return f"{text} (at {Path(frame.filename).name}:{frame.lineno} in {frame.name})"


def _row(case: Case, spec: dict, metrics: dict, runtime, peak, simulate_s, error) -> dict:
    return {"case_name": case.name, "variant": spec["name"], "family": spec["family"], "params": spec["params"],
            "case_spec": case.to_dict(), "metrics": metrics, "runtime_s": runtime, "peak_mem_mb": peak,
            "simulate_s": simulate_s, "error": error}


@dataclass
class RunOutcome:
    """What :func:`execute` did."""

    run_id: str
    resumed: bool
    cases_run: int
    cases_skipped: int
    rows_added: int
    elapsed_s: float


def run_config(suite: Suite, variants: list[Variant]) -> tuple[dict, str]:
    """Configuration of a run (suite digest, variants and parameters) and its digest.

    Parameters
    ----------
    suite : Suite
        The suite to run.
    variants : list of Variant
        The variants to run, with their parameters.

    Returns
    -------
    config : dict
        Suite name, source and digest, case count and variant specifications.
    digest : str
        SHA-256 hex digest of ``config``.
    """
    config = {"suite": suite.name, "suite_source": suite.source, "suite_digest": suite.digest(),
              "cases": len(suite.cases), "variants": variant_specs(variants)}
    return config, hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()


#: Default data-segment limit of a local worker process, GiB, and longest silence of a worker on a task, s.
MEMORY_LIMIT_GB = 6.0
TIMEOUT_S = 900.0


def execute(suite: Suite, variants: list[Variant], store: Store, workers: int | None = None,
            scheduler: str | None = None, resume: str | bool = True, progress: bool = True,
            notes: dict | None = None, memory_limit_gb: float | None = MEMORY_LIMIT_GB,
            timeout_s: float | None = TIMEOUT_S) -> RunOutcome:
    """Run every case of ``suite`` with ``variants`` and store the results.

    Parameters
    ----------
    suite : Suite
        The cases.
    variants : list of Variant
        The variants (with their parameters).
    store : Store
        Where results go.
    workers : int, optional
        Local worker processes (default: the processor count; 0 runs the
        cases in this process, without the protections below). Ignored
        with ``scheduler``.
    scheduler : str, optional
        Address of a Dask distributed scheduler (``tcp://host:port``) to
        send the cases to instead.
    resume : bool or str
        ``True``: continue the latest unfinished run with the same
        configuration and code commit, if any; ``False``: always start a
        new run; a run id: continue that run.
    progress : bool
        Show a progress bar.
    notes : dict, optional
        Notes stored with a new run.
    memory_limit_gb : float, optional
        Memory (data segment) limit of each local worker, GiB; a variant
        that exceeds it records a ``MemoryError`` (``None`` or 0: no limit).
    timeout_s : float, optional
        A local worker silent this long on a task is stopped and its
        variant recorded as timed out (``None``: no limit).

    Returns
    -------
    RunOutcome

    Examples
    --------
    One 9 cm leaf at 1.5 m in front of a wall, at a coarse step, with the raw
    cloud and the stray-point filter, in this process:

    >>> import tempfile, pathlib
    >>> from benchmarks.registry import get_variant
    >>> from benchmarks.store import Store
    >>> from benchmarks.suite import parse_suite
    >>> suite = parse_suite({"name": "tiny", "cases": [{"name": "leaf", "scanner": {"step_deg": 0.08},
    ...     "scene": {"generator": "single-leaf", "length_m": 0.09, "distance_m": 1.5, "seed": 7}}]})
    >>> store = Store(pathlib.Path(tempfile.mkdtemp()) / "results.sqlite")
    >>> outcome = execute(suite, [get_variant("raw"), get_variant("stray-point")], store, workers=0,
    ...                   progress=False)
    >>> rows = {row["variant"]: row["metrics"]["targets"][0] for row in store.results(outcome.run_id)}
    >>> rows["raw"]["rop_reduction"], rows["stray-point"]["rop_reduction"] > 0.5
    (0.0, True)
    """
    if not variants:
        raise BenchError("no variant to run")
    config, digest = run_config(suite, variants)
    commit = git_commit()
    if isinstance(resume, str):
        run_id = store.resolve(resume)
        if store.run_info(run_id)["config_digest"] != digest:
            raise BenchError(f"run {run_id} was started with another suite or other variants; "
                             "resume it with the same --suite, --variants and --set, or start a new run")
    else:
        run_id = store.find_resumable(digest, commit) if resume else None
    resumed = run_id is not None
    if run_id is None:
        run_id = store.create_run(suite.name, suite.digest(), config, digest, commit, notes)
    done = store.done_pairs(run_id)
    specs = dict(zip((v.name for v in variants), variant_specs(variants)))
    expected = {case.name: [specs[v.name] for v in variants if applies(v, case)] for case in suite.cases}
    todo = []
    for case in suite.cases:
        missing = [s for s in expected[case.name] if (case.name, s["name"]) not in done]
        if missing:
            todo.append((case.to_dict(), missing))
    start = time.perf_counter()
    added = 0
    remaining = {case["name"]: len(missing) for case, missing in todo}
    with tqdm(total=len(suite.cases), initial=len(suite.cases) - len(todo), unit="case", disable=not progress,
              desc=f"{suite.name} ({run_id})") as bar:
        for rows in _dispatch(todo, workers, scheduler, memory_limit_gb, timeout_s):
            added += store.add_results(run_id, rows)
            for row in rows:
                remaining[row["case_name"]] -= 1
                bar.update(remaining[row["case_name"]] == 0)
    if len(store.done_pairs(run_id)) == sum(len(v) for v in expected.values()):
        store.finish_run(run_id)
    return RunOutcome(run_id, resumed, len(todo), len(suite.cases) - len(todo), added,
                      time.perf_counter() - start)


def _dispatch(todo: list[tuple[dict, list[dict]]], workers: int | None, scheduler: str | None,
              memory_limit_gb: float | None, timeout_s: float | None):
    """Yield result rows as they arrive (inline, local worker processes or Dask)."""
    if not todo:
        return
    if scheduler:
        yield from _dispatch_dask(todo, scheduler)
    elif workers == 0:
        for case, specs in todo:
            for row in case_rows(case, specs):
                yield [row]
    else:
        yield from run_local(todo, workers or os.cpu_count() or 1, case_rows, _failed_row, _warm_up, memory_limit_gb,
                             timeout_s)


def _dispatch_dask(todo: list[tuple[dict, list[dict]]], address: str):
    from distributed import Client, as_completed

    try:
        client = Client(address, timeout="30s")
    except (OSError, TimeoutError) as exc:
        raise BenchError(f"cannot reach the Dask scheduler at {address!r} ({exc})") from None
    with client:
        futures = {client.submit(run_case, case, specs, pure=False): (case, specs) for case, specs in todo}
        try:
            for future in as_completed(futures):
                try:
                    yield future.result()
                except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: the case's variants get error rows
                    case, specs = futures[future]
                    yield [error_row(Case.from_dict(case), spec, f"Dask: {_message(exc)}") for spec in specs]
        finally:
            client.cancel(list(futures))
