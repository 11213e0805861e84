"""Real tree clouds against their published reference models (``tlsbench experiment woody-real``).

The clouds are the example trees of R packages shipped in ``tests/data/real``
(see its README for sources and licences): each is one tree cut out of a
terrestrial scan, without scanner position, normals or ground points, and
comes with a TreeQSM model published with it. Every cloud is run as a
forester would run it (``woody dbh`` and ``woody reconstruct`` with their
defaults: PCA normals oriented without a viewpoint, the ground found from the
points), each method in a fresh process so that its time and peak memory are
its own. Printed per cloud and method: the reference DBH and volume, ours,
the errors, the time and the peak memory above the process's start.

Further clouds (any format :func:`tlssim.formats.points.read_points` reads)
can be given with ``--cloud PATH``: they are run without a reference.
"""

from __future__ import annotations

import json
import multiprocessing
import resource
import time
from pathlib import Path

import numpy as np

from benchmarks.errors import BenchError

#: Folder of the shipped real clouds.
DATA = Path(__file__).resolve().parents[2] / "tests" / "data" / "real"
#: The shipped clouds: name, cloud file, reference model file (TreeQSM ``.mat`` or cylinder text table).
CLOUDS = (("rtwig-tree", "rtwig_cloud.txt", "rtwig_treeqsm.mat"),
          ("archi-tree1", "archi_tree1.las", "archi_tree1_treeqsm.txt"),
          ("treetraits-0744", "treetraits_tree_0744.laz", "treetraits_tree_0744_qsm.txt"))
#: Methods: DBH alone, STEP, cylinder following with the trunk first (``woody reconstruct`` defaults), and the same
#: on the points :func:`woody.leafwood.separate_wood` finds are wood (``woody reconstruct --separate``).
METHODS = ("dbh", "step", "cylinders", "cylinders-separated")
#: Columns a cylinder table with a header line must have (tReeTraits' export of a TreeQSM model).
HEADED_COLUMNS = frozenset({"startX", "startY", "startZ", "endX", "endY", "endZ", "radius_cyl", "length"})
#: Breast height of the references, m (TreeQSM's DBHqsm uses 1.3 m).
BREAST_HEIGHT_M = 1.3
#: Height of the horizontal slice of the cloud-based DBH reference, m (assumption: thin enough that a leaning
#: or tapering stem stays one circle, thick enough for a few hundred points of these clouds).
CLOUD_SLICE_M = 0.1
#: Points of the slice closer than this are one stem, m (assumption: four times the 5 cm spacing of the sparser
#: cloud, so that its stem is one group; a branch linked to it is trimmed by the fit).
CLOUD_LINK_M = 0.2
#: The points of the slice are linked through one point per cell of this size, m (assumption: small next to
#: ``CLOUD_LINK_M``).
LINK_CELL_M = 0.01
#: Points farther from the circle than this many robust sigmas (1.4826 x their median absolute distance) are
#: left out and the circle fitted again (the usual 3-sigma rule), up to ``CLOUD_ITERATIONS`` times.
CLOUD_TRIM_SIGMAS = 3.0
CLOUD_ITERATIONS = 10


def treeqsm_reference(path) -> dict:
    """Volume and DBH of a TreeQSM model: a ``.mat`` (``OptQSM`` or ``QSM`` struct) or its cylinder text table.

    The text table's columns are those TreeQSM's ``save_model_text`` writes: radius, length, start (3),
    axis (3), then parent, extension and more (only the first eight are read); a table with a header line is
    read by its column names instead (``startX`` ... ``endZ``, ``radius_cyl``, ``length``: tReeTraits' export).

    Parameters
    ----------
    path : str or Path
        The model file.

    Returns
    -------
    dict
        ``volume_m3`` (sum of the cylinder volumes), ``dbh_m`` (diameter of the thickest cylinder that crosses
        1.3 m above the lowest cylinder start), ``base_z_m`` (that start's height) and ``cylinders``.

    Raises
    ------
    BenchError
        If the file holds no cylinder table.
    """
    path = Path(path)
    if path.suffix == ".mat":
        from scipy.io import loadmat

        content = loadmat(path, squeeze_me=True, struct_as_record=False)
        model = next((content[k] for k in ("OptQSM", "QSM") if k in content), None)
        if model is None or not hasattr(model, "cylinder"):
            raise BenchError(f"{path}: no TreeQSM struct (OptQSM or QSM with a cylinder field)")
        c = model.cylinder
        radius, length = np.atleast_1d(c.radius).astype(float), np.atleast_1d(c.length).astype(float)
        start, axis = np.atleast_2d(c.start).astype(float), np.atleast_2d(c.axis).astype(float)
        end = start + axis * length[:, None]
    elif _has_header(path):
        table = np.genfromtxt(path, names=True)
        missing = HEADED_COLUMNS - set(table.dtype.names)
        if missing:
            raise BenchError(f"{path}: a cylinder table with a header needs the columns {', '.join(sorted(missing))}")
        table = np.atleast_1d(table)
        radius, length = table["radius_cyl"].astype(float), table["length"].astype(float)
        start = np.column_stack([table[k] for k in ("startX", "startY", "startZ")]).astype(float)
        end = np.column_stack([table[k] for k in ("endX", "endY", "endZ")]).astype(float)
    else:
        table = np.loadtxt(path, ndmin=2)
        if table.shape[1] < 8:
            raise BenchError(f"{path}: a TreeQSM cylinder table has at least 8 columns, this one {table.shape[1]}")
        radius, length, start, axis = table[:, 0], table[:, 1], table[:, 2:5], table[:, 5:8]
        end = start + axis * length[:, None]
    base = float(start[:, 2].min())
    z = base + BREAST_HEIGHT_M
    crossing = (np.minimum(start[:, 2], end[:, 2]) <= z) & (np.maximum(start[:, 2], end[:, 2]) >= z)
    return {"volume_m3": float((np.pi * radius**2 * length).sum()), "base_z_m": base, "cylinders": len(radius),
            "dbh_m": float(2 * radius[crossing].max()) if crossing.any() else float("nan")}


def _has_header(path: Path) -> bool:
    """Whether a text table's first line holds column names (not numbers)."""
    with open(path) as handle:
        first = handle.readline().split()
    try:
        [float(x) for x in first]
    except ValueError:
        return True
    return False


def cloud_dbh_reference(points, ground_z: float) -> dict:
    """DBH of the cloud itself: a plain least-squares circle through a horizontal slice at breast height.

    Independent of any QSM and of :func:`woody.dbh.measure_dbh`'s fit (no robust loss, no outlier rejection,
    no stem axis): the slice ``CLOUD_SLICE_M`` high centred 1.3 m above ``ground_z``, its largest group of
    points linked within ``CLOUD_LINK_M``, a Kåsa circle refined by geometric least squares. Only the ground
    height is shared with the method under test (pass the one it found, or a field value).

    Parameters
    ----------
    points : ndarray, (n, 3)
        The cloud, m.
    ground_z : float
        Ground height under the stem, m.

    Returns
    -------
    dict
        ``dbh_m``, ``ground_z_m``, ``n_points`` (in the stem's group), ``residual_m`` (RMS distance of those
        points from the circle).

    Raises
    ------
    BenchError
        If fewer than 10 points lie in the slice.
    """
    from scipy.optimize import least_squares
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    points = np.asarray(points, float)
    xy = points[np.abs(points[:, 2] - ground_z - BREAST_HEIGHT_M) <= CLOUD_SLICE_M / 2.0, :2]
    if len(xy) < 10:
        raise BenchError(f"{len(xy)} point(s) in the {CLOUD_SLICE_M} m slice {BREAST_HEIGHT_M} m above z = "
                         f"{ground_z:.3f} m: no stem there")
    # linked through one point per LINK_CELL_M cell: a dense slice (12,000 points on one 14 cm stem) would link
    # every pair of its points
    _, first, cell = np.unique(np.floor(xy / LINK_CELL_M).astype(np.int64), axis=0, return_index=True,
                               return_inverse=True)
    reps = cKDTree(xy[first])
    _, label = connected_components(reps.sparse_distance_matrix(reps, CLOUD_LINK_M), directed=False)
    xy = xy[label[cell.ravel()] == np.bincount(label[cell.ravel()]).argmax()]
    local = xy - xy.mean(axis=0)
    kept = np.ones(len(local), bool)
    for _ in range(CLOUD_ITERATIONS):  # trimmed least squares: a branch or twig next to the stem leaves the fit
        a, b, c = np.linalg.lstsq(np.column_stack([2 * local[kept], np.ones(kept.sum())]),
                                  (local[kept] ** 2).sum(axis=1), rcond=None)[0]
        start = np.array([a, b, np.sqrt(c + a * a + b * b)])
        fit = least_squares(lambda p: np.hypot(*(local[kept] - p[:2]).T) - p[2], start)
        residual = np.hypot(*(local - fit.x[:2]).T) - abs(fit.x[2])
        inside = np.abs(residual) <= CLOUD_TRIM_SIGMAS * 1.4826 * np.median(np.abs(residual[kept]))
        if (inside == kept).all() or inside.sum() < 10:
            break
        kept = inside
    return {"dbh_m": float(2 * abs(fit.x[2])), "ground_z_m": float(ground_z), "n_points": int(kept.sum()),
            "residual_m": float(np.sqrt(np.mean(fit.fun**2)))}


def _cloud_dbh(path) -> float:
    """The cloud-based DBH reference of a shipped cloud, 1.3 m above the ground :func:`woody.dbh.measure_dbh` finds."""
    from woody.cloud import read_cloud
    from woody.dbh import measure_dbh

    points = read_cloud(path).points
    return cloud_dbh_reference(points, measure_dbh(points)[0].ground_z_m)["dbh_m"]


def _measure(method: str, cloud_path: str, queue) -> None:
    """Run one method on one cloud (in a fresh process) and put its row on ``queue``."""
    from woody.cloud import read_cloud
    from woody.dbh import dbh_summary, measure_dbh

    points = read_cloud(cloud_path).points
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    start = time.perf_counter()
    row = {"method": method, "points": len(points)}
    try:
        if method == "dbh":
            stem = measure_dbh(points)[0]
            row.update(dbh_m=stem.dbh_m, flag=stem.flag, ground_z_m=stem.ground_z_m)
        else:
            if method == "step":
                from woody.step import step

                result = step(points)
            else:
                from woody.trunk import follow_tree

                result = follow_tree(points, separate=method == "cylinders-separated")
                if "wood_points" in result.stats:
                    row["wood_points"] = result.stats["wood_points"]
            row.update(volume_m3=result.volume, model_dbh_m=dbh_summary(points, result.cylinders())["model_dbh_m"])
    except Exception as exc:  # noqa: BLE001 - a method that fails on a real cloud is a result of the experiment
        row["error"] = f"{type(exc).__name__}: {exc}"
    row["time_s"] = time.perf_counter() - start
    row["peak_mb"] = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before, 0) / 1024.0
    queue.put(row)


def run(clouds=CLOUDS, extra=(), methods=METHODS, on_row=None) -> list[dict]:
    """Run each method on each cloud (one fresh process per run) and compare with the reference.

    Parameters
    ----------
    clouds : iterable of (name, cloud file, reference file)
        Clouds with a TreeQSM reference (files in :data:`DATA`).
    extra : iterable of str
        Paths of further clouds, run without a reference.
    methods : iterable of str
        Methods of :data:`METHODS` to run.
    on_row : callable, optional
        Called with each row as soon as it is done.

    Returns
    -------
    list of dict
        One row per cloud and method: ``cloud``, ``method``, ``points``, ``time_s``, ``peak_mb``, the reference
        (``ref_dbh_m``, ``ref_volume_m3``; ``ref_cloud_dbh_m``: :func:`cloud_dbh_reference`) and ours (``dbh_m``
        or ``model_dbh_m`` and ``volume_m3``) with their relative errors (``dbh_error``, ``cloud_dbh_error``,
        ``volume_error``), or ``error`` when the method failed.
    """
    unknown = set(methods) - set(METHODS)
    if unknown:
        raise BenchError(f"unknown method(s) {sorted(unknown)}; choose from {', '.join(METHODS)}")
    cases = [(name, DATA / cloud, {**treeqsm_reference(DATA / ref), "cloud_dbh_m": _cloud_dbh(DATA / cloud)})
             for name, cloud, ref in clouds]
    cases += [(Path(p).name, Path(p), None) for p in extra]
    context = multiprocessing.get_context("spawn")
    rows = []
    for name, path, reference in cases:
        if not path.exists():
            raise BenchError(f"{path}: no such cloud")
        for method in methods:
            queue = context.Queue()
            worker = context.Process(target=_measure, args=(method, str(path), queue))
            worker.start()
            row = {"cloud": name, **queue.get()}
            worker.join()
            if reference is not None:
                row.update(ref_dbh_m=reference["dbh_m"], ref_volume_m3=reference["volume_m3"])
                ours = row.get("dbh_m", row.get("model_dbh_m"))
                row["ref_cloud_dbh_m"] = reference["cloud_dbh_m"]
                if ours is not None:
                    row["dbh_error"] = ours / reference["dbh_m"] - 1.0
                    row["cloud_dbh_error"] = ours / reference["cloud_dbh_m"] - 1.0
                if "volume_m3" in row:
                    row["volume_error"] = row["volume_m3"] / reference["volume_m3"] - 1.0
            rows.append(row)
            if on_row is not None:
                on_row(row)
    return rows


def _cell(value, scale: float, digits: int) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value * scale:.{digits}f}"


def _line(row: dict) -> str:
    dbh = row.get("dbh_m", row.get("model_dbh_m"))
    text = (f"{row['cloud']:<14} {row['method']:<19} {row['points']:>8} {_cell(row.get('ref_dbh_m'), 100, 2):>8} "
            f"{_cell(row.get('ref_cloud_dbh_m'), 100, 2):>8} {_cell(dbh, 100, 2):>8} "
            f"{_cell(row.get('dbh_error'), 100, 1):>7} {_cell(row.get('cloud_dbh_error'), 100, 1):>7} "
            f"{_cell(row.get('ref_volume_m3'), 1e3, 2):>9} {_cell(row.get('volume_m3'), 1e3, 2):>9} "
            f"{_cell(row.get('volume_error'), 100, 1):>7} {row['time_s']:>8.1f} {row['peak_mb']:>8.0f}")
    if "error" in row:
        text += f"  {row['error']}"
    elif "flag" in row:
        text += f"  {row['flag']}"
    elif "wood_points" in row:
        text += f"  wood {row['wood_points']}"
    return text


HEADER = (f"{'cloud':<14} {'method':<19} {'points':>8} {'refDBH':>8} {'cloudDBH':>8} {'DBH_cm':>8} {'err_%':>7} "
          f"{'cerr_%':>7} "
          f"{'ref_dm3':>9} {'vol_dm3':>9} {'err_%':>7} {'time_s':>8} {'peak_MB':>8}")


def add_parser(sub) -> None:
    """Register ``woody-real`` with the ``tlsbench experiment`` sub-commands."""
    p = sub.add_parser("woody-real", help="woody on real tree clouds against their published QSMs",
                       description=__doc__.splitlines()[0])
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated subset of {','.join(METHODS)}")
    p.add_argument("--only", default=None, help="comma-separated names of the shipped clouds to run "
                                                f"({','.join(c[0] for c in CLOUDS)}; default all)")
    p.add_argument("--cloud", action="append", default=[], help="a further cloud file, run without a reference")
    p.add_argument("--json", default=None, help="write the rows to this JSON file")
    p.set_defaults(func=run_command)


def run_command(args) -> int:
    """Run the experiment with the parsed arguments and print one line per cloud and method."""
    names = None if args.only is None else set(args.only.split(","))
    if names is not None and names - {c[0] for c in CLOUDS}:
        raise BenchError(f"unknown cloud(s) {sorted(names - {c[0] for c in CLOUDS})}; shipped: "
                         f"{', '.join(c[0] for c in CLOUDS)}")
    clouds = [c for c in CLOUDS if names is None or c[0] in names]
    print(HEADER)
    rows = run(clouds, args.cloud, tuple(args.methods.split(",")), on_row=lambda row: print(_line(row), flush=True))
    print("reference: the TreeQSM model published with each cloud (DBH 1.3 m above its base; volume of its "
          "cylinders); cloudDBH: a trimmed least-squares circle of the cloud's 10 cm slice 1.3 m above the ground "
          "woody dbh finds (cerr: error against it); peak memory = peak RSS of the run above its start")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0
