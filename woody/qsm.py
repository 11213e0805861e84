"""Cylinder tables in the layout of TreeQSM (Raumonen et al. 2013), for tools that read quantitative structure models.

One row per cylinder, with TreeQSM's conventions: rows numbered from 1,
``parent`` and ``extension`` are row numbers (0: none; the extension is the
next cylinder of the same branch), ``branch`` numbers the branches from 1
and ``order`` is the branching order (0 for the trunk; a list that counts
the trunk as order 1, as cylinder following does, is shifted; -1 where a
method gives no order). A frustum of the
cylinder list (two radii) becomes the straight cylinder of the same length
and volume, ``radius = sqrt((r0² + r0 r1 + r1²) / 3)``, so that the table's
volume equals the model's.

Columns: ``radius, length, start_x, start_y, start_z, axis_x, axis_y,
axis_z, parent, extension, branch, order, position_in_branch`` (metres;
``axis`` a unit vector from ``start``).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from woody.errors import WoodyError
from woody.geometry import cylinder_arrays

COLUMNS = ("radius", "length", "start_x", "start_y", "start_z", "axis_x", "axis_y", "axis_z", "parent", "extension",
           "branch", "order", "position_in_branch")


def qsm_table(cylinders: list[dict]) -> dict[str, np.ndarray]:
    """The TreeQSM-style columns of a cylinder list (see the module for the conventions).

    Zero-length cylinders are left out (their children are re-attached to
    their parent).

    Parameters
    ----------
    cylinders : list of dict
        Cylinder list (``id``, ``parent``, ``branch``, ``order``, ``start``,
        ``end``, ``radius_m``, optional ``radius_end_m``).

    Returns
    -------
    dict of str to ndarray
        One array per name of :data:`COLUMNS`.
    """
    arr = cylinder_arrays(cylinders)
    axis = arr["end"] - arr["start"]
    length = np.linalg.norm(axis, axis=1)
    keep = length > 0
    parent_of = dict(zip(arr["id"].tolist(), arr["parent"].tolist()))
    row_of = {cid: row + 1 for row, cid in enumerate(arr["id"][keep].tolist())}

    def kept_parent(cid):
        seen = set()
        while cid in parent_of and cid not in row_of and cid not in seen:
            seen.add(cid)
            cid = parent_of[cid]
        return row_of.get(cid, 0)

    parent = np.array([kept_parent(p) for p in arr["parent"][keep].tolist()], np.int64)
    branch_ids = arr["branch"][keep]
    _, branch = np.unique(branch_ids, return_inverse=True)
    branch = branch.reshape(-1) + 1
    count = int(keep.sum())
    extension = np.zeros(count, np.int64)
    for row in range(count):
        p = parent[row]
        if p and branch[p - 1] == branch[row] and extension[p - 1] == 0:
            extension[p - 1] = row + 1
    position = np.zeros(count, np.int64)
    for row in range(count):  # rows of a branch follow their parents in a cylinder list
        p = parent[row]
        position[row] = position[p - 1] + 1 if p and branch[p - 1] == branch[row] else 1
    r0, r1 = arr["r0"][keep], arr["r1"][keep]
    return {"radius": np.sqrt((r0 * r0 + r0 * r1 + r1 * r1) / 3.0), "length": length[keep],
            **{f"start_{a}": arr["start"][keep, i] for i, a in enumerate("xyz")},
            **{f"axis_{a}": axis[keep, i] / length[keep] for i, a in enumerate("xyz")},
            "parent": parent, "extension": extension, "branch": branch, "order": _orders(arr["order"][keep]),
            "position_in_branch": position}


def _orders(order: np.ndarray) -> np.ndarray:
    """Branching orders from 0 for the trunk (lists that count the trunk as order 1 are shifted; -1: unknown)."""
    if len(order) and (order >= 0).all():
        return order - order.min()
    return order


def write_qsm_csv(cylinders: list[dict], path) -> Path:
    """Write the TreeQSM-style table of a cylinder list as CSV (a header row, then one row per cylinder).

    Parameters
    ----------
    cylinders : list of dict
        Cylinder list.
    path : str or Path
        Output file.

    Returns
    -------
    Path
    """
    table = qsm_table(cylinders)
    path = Path(path)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(COLUMNS)
        for row in range(len(table["radius"])):
            writer.writerow([repr(float(table[c][row])) if table[c].dtype.kind == "f" else int(table[c][row])
                             for c in COLUMNS])
    return path


def read_qsm_csv(path) -> list[dict]:
    """Read a table written by :func:`write_qsm_csv` back as a cylinder list (ids are the row numbers, from 1).

    Raises
    ------
    WoodyError
        If the file lacks a column or holds a value that is not a number.
    """
    path = Path(path)
    try:
        with open(path, newline="") as handle:
            rows = list(csv.DictReader(handle))
        out = []
        for number, row in enumerate(rows, start=1):
            start = np.array([float(row[f"start_{a}"]) for a in "xyz"])
            axis = np.array([float(row[f"axis_{a}"]) for a in "xyz"])
            length, radius = float(row["length"]), float(row["radius"])
            out.append({"id": number, "parent": int(row["parent"]) or -1, "branch": int(row["branch"]),
                        "order": int(row["order"]), "start": start.tolist(),
                        "end": (start + length * axis).tolist(), "radius_m": radius, "radius_end_m": radius})
    except (KeyError, TypeError, ValueError, OSError, UnicodeDecodeError) as exc:
        raise WoodyError(f"{path}: not a TreeQSM-style cylinder table ({type(exc).__name__}: {exc})") from None
    return out
