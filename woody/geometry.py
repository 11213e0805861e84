"""Geometry shared by both methods: frusta, cylinder lists, branch records' sections, distances and tube meshes.

Both methods report their result as a *cylinder list*, the format of a woody
object's truth in ``docs/contracts.md``: dicts with ``id``, ``parent`` (-1
for a root), ``order``, ``branch``, ``start`` and ``end`` ([x, y, z], m),
``radius_m`` (at ``start``) and ``radius_end_m`` (at ``end``). A cylinder with
two radii is a frustum (truncated cone).
"""

from __future__ import annotations

import numpy as np

from woody.errors import WoodyError


def orthonormal_frame(normal, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Right-handed frame ``(u, v, n)`` with ``n`` along ``normal`` and ``v`` as close to ``up`` as possible.

    The same construction as :func:`scenes.primitives.orthonormal_frame`,
    kept here so that reconstruction does not load the scene library.

    Parameters
    ----------
    normal : array_like, shape (3,)
        Direction of the frame's third axis (need not be unit length).
    up : array_like, shape (3,), optional
        Preferred direction of the second axis; replaced by +x when it is
        parallel to ``normal`` (+y when ``normal`` is along x too).

    Returns
    -------
    u, v, n : ndarray, shape (3,)
        Unit vectors with ``u × v = n``.
    """
    n = np.asarray(normal, dtype=float)
    length = np.linalg.norm(n)
    if not np.isfinite(length) or length == 0:
        raise WoodyError(f"a direction must be a finite non-zero vector, got {normal!r}")
    n = n / length
    up = np.asarray(up, dtype=float)
    v = up - np.dot(up, n) * n
    if np.linalg.norm(v) < 1e-9:
        v = np.array([1.0, 0.0, 0.0]) - n[0] * n
    if np.linalg.norm(v) < 1e-9:  # normal and up both along x
        v = np.array([0.0, 1.0, 0.0]) - n[1] * n
    v /= np.linalg.norm(v)
    # v x n element by element, with the products and differences of np.cross (same bits, less overhead).
    (v0, v1, v2), (n0, n1, n2) = v.tolist(), n.tolist()
    return np.array([v1 * n2 - v2 * n1, v2 * n0 - v0 * n2, v0 * n1 - v1 * n0]), v, n


def frustum_volume(r0, r1, length):
    """Volume of frusta of end radii ``r0``, ``r1`` and axis ``length`` (m^3).

    Parameters
    ----------
    r0 : float or array_like
        Radius at the start of each frustum, m.
    r1 : float or array_like
        Radius at the end of each frustum, m.
    length : float or array_like
        Axis length of each frustum, m.

    Returns
    -------
    ndarray
        Volumes, m^3 (broadcast shape of the arguments).
    """
    r0, r1 = np.asarray(r0, float), np.asarray(r1, float)
    return np.pi * np.asarray(length, float) * (r0 * r0 + r0 * r1 + r1 * r1) / 3.0


def cylinder_arrays(cylinders: list[dict]) -> dict[str, np.ndarray]:
    """Columns of a cylinder list: ``start``, ``end`` (m, 3), ``r0``, ``r1``, ``id``, ``parent``, ``branch``, ``order``.

    A missing ``radius_end_m`` equals ``radius_m``; a missing or ``None`` id
    is the row number, parent -1, branch the row number and order -1.
    """
    count = len(cylinders)
    out = {
        "start": np.array([c["start"] for c in cylinders], float).reshape(count, 3),
        "end": np.array([c["end"] for c in cylinders], float).reshape(count, 3),
        "r0": np.array([c["radius_m"] for c in cylinders], float),
        "r1": np.array([c.get("radius_end_m", c["radius_m"]) for c in cylinders], float),
    }
    defaults = {"id": lambda i: i, "parent": lambda i: -1, "branch": lambda i: i, "order": lambda i: -1}
    for key, default in defaults.items():
        out[key] = np.array([default(i) if c.get(key) is None else c[key] for i, c in enumerate(cylinders)],
                            np.int64).reshape(count)
    return out


def section_arrays(records: list[dict]) -> tuple:
    """Every section of branch records (``sections`` as ``(start, end, radius)``, ``reliable`` per section) as
    arrays: starts and ends (m), radii (m), the owning record's index, resolved (absent ``reliable``: all)."""
    starts = np.array([s[0] for r in records for s in r["sections"]], float)
    ends = np.array([s[1] for r in records for s in r["sections"]], float)
    radii = np.array([s[2] for r in records for s in r["sections"]], float)
    owner = np.array([i for i, r in enumerate(records) for _ in r["sections"]])
    reliable = np.array([ok for r in records for ok in r.get("reliable", [True] * len(r["sections"]))], bool)
    return starts, ends, radii, owner, reliable


def cylinders_volume(cylinders: list[dict]) -> float:
    """Total volume of a cylinder list, m^3 (each entry a frustum)."""
    if not cylinders:
        return 0.0
    arr = cylinder_arrays(cylinders)
    return float(frustum_volume(arr["r0"], arr["r1"], np.linalg.norm(arr["end"] - arr["start"], axis=1)).sum())


def segment_distance(points: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance of points to segments and the clipped axial parameter.

    Parameters
    ----------
    points : ndarray, (m, 3)
    start, end : ndarray, (3,) or (m, 3)
        Segment end points (one segment for all points, or one per point).

    Returns
    -------
    distance : ndarray, (m,)
        Euclidean distance to the segment, m.
    t : ndarray, (m,)
        Position of the closest segment point, 0 at ``start``, 1 at ``end``.
    """
    return axis_distance(points, *segment_axis(start, end))


def segment_axis(start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The constants of :func:`axis_distance` for segments ``start -> end``.

    Parameters
    ----------
    start, end : ndarray, (3,) or (m, 3)
        Segment ends, m.

    Returns
    -------
    start : ndarray
        As given, m.
    axis : ndarray
        ``end - start``, m.
    length2 : ndarray
        Squared length of ``axis`` (1 for a zero-length segment), m^2.
    """
    axis = end - start
    length2 = np.einsum("...i,...i->...", axis, axis)
    return start, axis, np.where(length2 > 0, length2, 1.0)


def axis_distance(points: np.ndarray, start: np.ndarray, axis: np.ndarray,
                  length2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`segment_distance` from the constants of :func:`segment_axis` (a segment reused for many queries).

    Parameters
    ----------
    points : ndarray, (m, 3)
        Query points, m.
    start, axis, length2 : ndarray
        The segment's start (m), ``end - start`` (m) and squared length (m^2), from :func:`segment_axis`.

    Returns
    -------
    distance : ndarray, (m,)
        Euclidean distance to the segment, m.
    t : ndarray, (m,)
        Position of the closest segment point, 0 at ``start``, 1 at ``end``.
    """
    t = np.einsum("...i,...i->...", points - start, axis) / length2
    t = np.clip(t, 0.0, 1.0)
    gap = points - (start + t[..., None] * axis)
    return np.sqrt(np.add.reduce(gap * gap, axis=-1)), t  # np.linalg.norm(gap, axis=-1), without its overhead


def ring_frames(tangents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Twist-free frames ``(u, v)`` perpendicular to a sequence of unit tangents (parallel transport)."""
    u = np.empty_like(tangents)
    u[0] = orthonormal_frame(tangents[0])[0]
    for i in range(1, len(tangents)):
        carried = u[i - 1] - np.dot(u[i - 1], tangents[i]) * tangents[i]
        norm = np.linalg.norm(carried)
        u[i] = carried / norm if norm > 1e-9 else orthonormal_frame(tangents[i])[0]
    return u, np.cross(tangents, u)


def tube_mesh(centres: np.ndarray, tangents: np.ndarray, radii: np.ndarray, sections: int = 16):
    """A closed triangle mesh through a sequence of circles (a tuboid or a single frustum).

    Parameters
    ----------
    centres, tangents : ndarray, (k, 3)
        Circle centres (m) and unit normals of the circle planes, k >= 2.
    radii : ndarray, (k,)
        Circle radii, m.
    sections : int
        Vertices per circle.

    Returns
    -------
    trimesh.Trimesh
    """
    import trimesh

    k = len(centres)
    u, v = ring_frames(np.asarray(tangents, float))
    angle = 2.0 * np.pi * np.arange(sections) / sections
    rings = centres[:, None, :] + radii[:, None, None] * (np.cos(angle)[None, :, None] * u[:, None, :]
                                                          + np.sin(angle)[None, :, None] * v[:, None, :])
    vertices = np.concatenate([rings.reshape(-1, 3), centres[[0, -1]]])
    j = np.arange(sections)
    jn = (j + 1) % sections
    faces = []
    for i in range(k - 1):
        a, b = i * sections + j, (i + 1) * sections + j
        an, bn = i * sections + jn, (i + 1) * sections + jn
        faces += [np.column_stack([a, an, bn]), np.column_stack([a, bn, b])]
    first, last = k * sections, k * sections + 1
    faces += [np.column_stack([np.full(sections, first), jn, j]),
              np.column_stack([np.full(sections, last), (k - 1) * sections + j, (k - 1) * sections + jn])]
    return trimesh.Trimesh(vertices, np.concatenate(faces), process=False)


def cylinders_mesh(cylinders: list[dict], sections: int = 16):
    """One closed frustum mesh per cylinder of a cylinder list, concatenated (trimesh.Trimesh).

    Parameters
    ----------
    cylinders : list of dict
        Cylinder records (``start``, ``end``, ``radius_m``, optional ``radius_end_m``, all m), as
        :func:`cylinder_arrays` reads them.
    sections : int
        Number of sides of each frustum's polygonal cross-section.

    Returns
    -------
    trimesh.Trimesh
        The concatenated meshes, vertices in m.
    """
    import trimesh

    arr = cylinder_arrays(cylinders)
    meshes = []
    for start, end, r0, r1 in zip(arr["start"], arr["end"], arr["r0"], arr["r1"]):
        axis = end - start
        length = np.linalg.norm(axis)
        if length > 0:
            tangent = np.repeat((axis / length)[None], 2, axis=0)
            meshes.append(tube_mesh(np.array([start, end]), tangent, np.array([r0, r1]), sections))
    return trimesh.util.concatenate(meshes) if meshes else trimesh.Trimesh()
