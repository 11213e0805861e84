"""Hidden stretches of a limb: cylinders across the gap between a branch and the wood it grows from.

A single scan of a leafy tree loses a limb's stretch behind the leaves (a simulated leafy Conference pear:
0-10 points per 5 cm over 0.1-1.1 m of a 51 mm leader, 50-140 per 5 cm above). Cylinder following starts
the part beyond the gap as a child of whatever lies across it (``FollowParams.bridge_m``), often a chain of
fragments fitted to the few points in the gap, but the gap itself gets no wood. TreeQSM joins a child's
first cylinder to its parent's surface (Raumonen et al. 2013, Remote Sens. 5: 491-520; spec
``woody.md``); here the evidence has to come from both sides of the gap:

- beyond it, a branch's first section the points resolve (``reliable``): its axis, the chord over its
  first :data:`CHORD_RADII` radii, is the line the limb runs along. The branch's unresolved sections before
  it, if each runs forward along that line, are part of the stretch and are replaced by the fill: where
  leaves split a limb into strips of its surface, the points do not resolve its radius (on the trees suite's
  leafy pear seed 14 a leader 35-41 mm across came out over 0.29 m as four unresolved sections of 9.0-13.8 mm
  radius below its first resolved one, 15.2 mm; round 34, before which only a branch whose first section was
  resolved was filled);
- before it, that line extended back meets a resolved section at least as wide as the branch (a limb grows
  from wood no thinner than itself, the pipe model) within ``bridge_m``, after running through no such
  wood for at least :data:`GAP_RADII` of the branch's radii (a branch that starts on its parent's surface
  has no hidden stretch);
- the scan saw the limb somewhere in the stretch: a point lies between :data:`SHELL` times its radius from
  the line, away from its ends by the radius (leaves let a few pulses through; a gap between two pieces of
  wood that the scan saw empty is no hidden stretch);
- the branch carries at least as much length (its sections and its descendants') as the stretch to fill:
  a short piece's line is too uncertain to carry far (on the trees suite's vine seed 3 a 2 cm piece was
  filled over 38 cm, 0.12 dm3 beside the wood, before this condition).

The stretch between is filled with cylinders along that line whose radii follow the pipe model from the
branch's first resolved section: ``r0 sqrt((G + t) / G)`` at a distance ``t`` back from it, ``G`` the growth
length the branch carries (its sections and its descendants'), at most the radius of the wood the line meets.
A twig that starts on a limb, or whose line meets only thinner wood, is left alone.

Where leaf shadows split a limb's stretch into strips of its surface, each followed as an unresolved piece of
its own whose axis lies on the limb's surface, the strips are the evidence instead (:func:`extend_over_strips`,
after :func:`fill_gaps`): the limb is extended back from its first resolved section along its line as far as
they run, with the same pipe-model radii.

On the trees suite (``benchmarks/suites/trees.yaml``) the leafy pears' volume errors went from -26.2 / -18.1
/ -28.3 % to -21.8 / -15.4 / -25.7 %. Known failure: at a four-way fork, a leader's first section fitted
5 cm off the leader gives a fill beside the wood (the quick suite's leafy tree at 0.08 deg with the trunk
fitted first: one fill of 0.35 dm3, all of it false volume, +13.2 -> +16.5 %; 0.50 dm3 once the stem ends at
the fork, :mod:`woody.fork`). Its section's points lie on its circle (median distance 31 mm from the axis of a
28 mm section), a narrow arc: a test of the axis against its own points does not single it out.
"""

from __future__ import annotations

import numpy as np

from woody.geometry import section_arrays, segment_distance

#: Length of a branch's axis chord, in radii of its first section (assumption: 20 radii, 20 cm on a 1 cm limb,
#: average the wobble of the 4-radius sections of :func:`woody.cylinders.follow_cylinders` while a limb bends
#: little over it).
CHORD_RADII = 20.0
#: Distances from the filled line within which a point counts as seen on the limb, in radii of the branch's
#: first section (assumption: the surface at one radius, give or take half of it for range noise and taper).
SHELL = (0.5, 1.5)
#: Shortest hidden stretch that is filled, in radii of the branch's first section (assumption: one output
#: section, 4 radii; shorter gaps are within the fit's own reach).
GAP_RADII = 4.0
#: An unresolved section narrower than this fraction of a limb's radius, on the limb's line behind its first
#: resolved section, is a strip of its surface (:func:`extend_over_strips`). Assumption, from nine simulated
#: leafy pears (round 34): where leaf shadows split a 20-50 mm leader's base into strips, the pipe model and the
#: footprint bound held them at their strips' width, and the leaders' matched volume lost 0.73-2.44 dm3 per tree
#: to pieces under half the true radius against 0-0.46 to those within it.
STRIP_WIDTH = 0.5
#: The points within ``SHELL[1]`` radii of a stretch extended over strips must lie at a median distance from its
#: line of at least (1 - this fraction) of its radius: the fill must not run through the limb's points (the same
#: tolerance as :data:`woody.cylinders.RESOLVED_SCATTER`). A first section fitted too wide or beside its limb
#: puts its line among them (the quick suite's leafy tree, followed with its trunk first: a 35 mm section on a
#: 17 mm limb, its stretch's points at a median 0.73 of its radius, 3.2 dm3 of false volume); a first section
#: fitted too thin leaves them farther out (a pear's 21 mm leader under an 18 mm section: 1.26), the fill on the
#: safe side.
SURFACE_SCATTER = 0.25
#: Most samples along a ray (numerics: a first radius fitted near zero to collinear points would otherwise ask
#: for billions; on a 1 m reach the samples stay at most 0.1 mm apart).
RAY_SAMPLES = 10_000


def fill_gaps(records: list[dict], points: np.ndarray, bridge_m: float, section_radii: float) -> int:
    """Prepend to each branch record the cylinders of its hidden stretch, in place of its unresolved sections
    before its first resolved one (see the module docstring).

    Parameters
    ----------
    records : list of dict
        Branch records of :func:`woody.cylinders.follow_cylinders` (``id``, ``parent``, ``children``,
        ``start``, ``sections`` as ``(start, end, radius)`` in m, ``reliable`` per section), parents first.
    points : ndarray, (n, 3)
        The fitted cloud, m.
    bridge_m : float
        Longest stretch filled, m (``FollowParams.bridge_m``).
    section_radii : float
        Length of a filling cylinder, in its radii (``FollowParams.section_radii``; 0: one cylinder).

    Returns
    -------
    int
        Number of branches whose hidden stretch was filled.
    """
    if bridge_m <= 0 or len(records) < 2:
        return 0
    starts, ends, radii, owner, reliable = section_arrays(records)
    index = {r["id"]: i for i, r in enumerate(records)}
    carried = _growth_lengths(records, index)
    fills = []
    for i, record, first, origin, direction, r0 in _limb_lines(records):
        if not _forward(record["sections"][:first], direction):
            continue
        subtree = _subtree(records, index, i)
        wood = reliable & (radii >= r0) & ~np.isin(owner, subtree)
        hit = _first_hit(origin, -direction, bridge_m, starts[wood], ends[wood], radii[wood], step=r0 / 2)
        if hit is None or not GAP_RADII * r0 <= hit[0] <= carried[i] or \
                not _seen(points, origin, origin - hit[0] * direction, r0):
            continue
        fills.append((i, first, origin, direction, r0, hit, carried[i]))
    for i, first, origin, direction, r0, (gap, limit), grown in fills:
        record = records[i]
        _replace_start(record, first, _fill(origin, direction, gap, r0, grown, limit, section_radii))
    return len(fills)


def extend_over_strips(records: list[dict], points: np.ndarray, bridge_m: float, section_radii: float) -> int:
    """Extend each limb back from its first resolved section over the strips of its surface behind it, in place.

    Leaf shadows split a limb's stretch into strips of its visible surface, each followed as a piece of its own
    (often a chain of fragments, each the child of the last) whose points do not resolve the limb's radius: the
    pipe model and the footprint bound hold them near the strip's width, and their axes lie on the limb's
    surface, a radius off its axis. On the scored 20-50 mm leaders of simulated leafy pears (0.036 deg, 4 m)
    11.7 of the 14.4 dm3 of seen volume missed over nine trees lay beside such pieces, their axes 1-2 radii off
    the limb's (round 35). :func:`fill_gaps` fills such a stretch only where the limb's line meets wood behind
    it; here the strips themselves are the evidence. Behind a branch's first resolved section (radius ``r0``,
    line: its chord, as in :func:`fill_gaps`), the unresolved sections narrower than :data:`STRIP_WIDTH` ``r0``
    whose middles lie within ``SHELL[1] r0`` of the line, each starting at most :data:`GAP_RADII` ``r0`` beyond
    the reach of those before it, make the stretch (at most ``bridge_m``; up to the first resolved wood at
    least ``r0`` wide the line meets, including the stretches extended before). It is filled as
    :func:`fill_gaps` fills, when it is at least :data:`GAP_RADII` ``r0`` long, at most the growth length
    the branch carries, and the points beside it lie on the limb's surface (:func:`_on_surface`). The strips'
    own sections stay (their volume is a small fraction: under ``STRIP_WIDTH ** 2`` of the fill's); the branch's
    unresolved sections before its first resolved one are replaced. Runs after :func:`fill_gaps` (a branch filled
    there meets its filled wood at once).

    Parameters
    ----------
    records : list of dict
        Branch records of :func:`woody.cylinders.follow_cylinders` (``id``, ``parent``, ``children``,
        ``sections`` as ``(start, end, radius)`` in m, ``reliable`` per section), parents first.
    points : ndarray, (n, 3)
        The fitted cloud, m.
    bridge_m : float
        Longest stretch extended over, m (``FollowParams.bridge_m``).
    section_radii : float
        Length of a filling cylinder, in its radii (``FollowParams.section_radii``; 0: one cylinder).

    Returns
    -------
    int
        Number of branches extended.
    """
    if bridge_m <= 0 or len(records) < 2:
        return 0
    starts, ends, radii, owner, reliable = section_arrays(records)
    index = {r["id"]: i for i, r in enumerate(records)}
    carried = _growth_lengths(records, index)
    added_wood: list[tuple] = []
    count = 0
    for i, record, first, origin, direction, r0 in _limb_lines(records):
        reach = _strip_reach(origin, direction, r0, starts, ends, radii, reliable, bridge_m)
        if reach < GAP_RADII * r0:
            continue
        wood = reliable & (radii >= r0) & ~np.isin(owner, _subtree(records, index, i))
        met = [(a, e, r) for a, e, r in zip(starts[wood], ends[wood], radii[wood])] + added_wood
        hit = _first_hit(origin, -direction, reach, np.array([m[0] for m in met], float).reshape(-1, 3),
                         np.array([m[1] for m in met], float).reshape(-1, 3), np.array([m[2] for m in met], float),
                         step=r0 / 2)
        limit = np.inf
        if hit is not None:
            reach, limit = min(reach, hit[0]), hit[1]
        if not GAP_RADII * r0 <= reach <= carried[i] or not _on_surface(points, origin, origin - reach * direction, r0):
            continue
        added = _fill(origin, direction, reach, r0, carried[i], limit, section_radii)
        _replace_start(record, first, added)
        added_wood += added
        count += 1
    return count


def _limb_lines(records: list[dict]):
    """Each branch record with a parent and a resolved section, as ``(index, record, first, origin, direction,
    r0)``: its first resolved section's index and the line of its chord from there (:func:`_chord`), generated as
    the loop goes (a record changed in the loop is read changed)."""
    for i, record in enumerate(records):
        first = _first_resolved(record)
        line = None if record["parent"] < 0 or first is None else _chord(record["sections"][first:])
        if line is not None:
            yield (i, record, first, *line)


def _replace_start(record: dict, first: int, added: list) -> None:
    """Put the filled sections ``added`` before a branch record's first resolved one (index ``first``), in place of
    its unresolved sections there. The filled radii are the pipe model's from a resolved section: marked
    resolved, a later pass of the pipe model (woody.trunk.follow_tree) does not shrink them to a thin parent's."""
    reliable = list(record.get("reliable", [True] * len(record["sections"])))
    record["reliable"] = [True] * len(added) + reliable[first:]
    record["sections"] = added + list(record["sections"][first:])
    record["start"] = list(added[0][0])


def _strip_reach(origin: np.ndarray, direction: np.ndarray, r0: float, starts: np.ndarray, ends: np.ndarray,
                 radii: np.ndarray, reliable: np.ndarray, bridge_m: float) -> float:
    """How far back (m, at most ``bridge_m``) from ``origin`` along the line ``-direction`` the strips of a limb
    of radius ``r0`` (m) reach without a break longer than :data:`GAP_RADII` ``r0`` (see
    :func:`extend_over_strips`); 0 when none lies behind it."""
    middle = (starts + ends) / 2
    along = (middle - origin) @ direction
    off = np.linalg.norm(middle - origin - along[:, None] * direction, axis=1)
    strip = ~reliable & (radii < STRIP_WIDTH * r0) & (along < 0) & (-along <= bridge_m) & (off <= SHELL[1] * r0)
    back_a, back_e = -((starts - origin) @ direction), -((ends - origin) @ direction)
    near, far = np.minimum(back_a, back_e)[strip], np.maximum(back_a, back_e)[strip]
    reach = 0.0
    for k in np.argsort(near, kind="stable"):
        if near[k] > reach + GAP_RADII * r0:
            break
        reach = max(reach, float(far[k]))
    return min(reach, bridge_m)


def _on_surface(points: np.ndarray, close: np.ndarray, far: np.ndarray, r0: float) -> bool:
    """Whether the points (m) within ``SHELL[1] r0`` (m) of the line ``close -> far`` (m), projecting inside it, lie
    at a median distance from it of at least ``(1 -`` :data:`SURFACE_SCATTER` ``) r0`` (False when there are
    none)."""
    distance, t = segment_distance(points, close, far)
    near = distance[(t > 0) & (t < 1) & (distance <= SHELL[1] * r0)]
    return bool(len(near)) and float(np.median(near)) >= (1.0 - SURFACE_SCATTER) * r0


def _first_resolved(record: dict) -> int | None:
    """Index of a branch record's first section the points resolve (``reliable``; absent: resolved); None when
    there is none."""
    reliable = record.get("reliable", [True] * len(record["sections"]))
    return next((k for k, ok in enumerate(reliable) if ok), None)


def _forward(sections: list[tuple], direction: np.ndarray) -> bool:
    """Whether each of a branch's ``sections`` (m) before its first resolved one runs forward along the line of
    its limb (unit ``direction``): a piece grown back towards the wood the line meets is no stretch of that limb
    (the quick suite's leafy tree at 0.08 deg with the trunk fitted first: a 7.8 mm piece running back down, 4
    radii off the line, below a leader section fitted at 18.7 mm beside the leader; filled, 0.57 m and 0.64 dm3
    of false volume)."""
    return all(float(np.dot(np.subtract(end, start), direction)) > 0 for start, end, _ in sections)


def _chord(sections: list[tuple]) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Start (m), unit direction and first radius (m) of a branch's axis chord over its first
    :data:`CHORD_RADII` radii; None for a branch of no length."""
    origin = np.asarray(sections[0][0], float)
    r0 = float(sections[0][2])
    if r0 <= 0:
        return None
    end = np.asarray(sections[0][1], float)
    for _, end_k, _ in sections[1:]:
        if np.linalg.norm(np.asarray(end_k, float) - origin) > CHORD_RADII * r0:
            break
        end = np.asarray(end_k, float)
    length = float(np.linalg.norm(end - origin))
    return (origin, (end - origin) / length, r0) if length > 0 else None


def _first_hit(origin: np.ndarray, direction: np.ndarray, reach: float, starts: np.ndarray, ends: np.ndarray,
               radii: np.ndarray, step: float) -> tuple[float, float] | None:
    """Distance along the ray ``origin + t direction`` (``0 <= t <= reach``, m) at which it first lies inside one
    of the cylinders ``starts -> ends`` (m) of ``radii`` (m), sampled every ``step`` m (at most
    :data:`RAY_SAMPLES` samples), and that cylinder's radius; None when it meets none."""
    if not len(radii):
        return None
    middle = (starts + ends) / 2
    half = np.linalg.norm(ends - starts, axis=1) / 2
    near, _ = segment_distance(middle, origin, origin + reach * direction)
    keep = np.flatnonzero(near <= half + radii)
    if not len(keep):
        return None
    step = max(step, reach / RAY_SAMPLES)
    t = np.arange(0.0, reach + step / 2, step)
    ray = origin[None] + t[:, None] * direction[None]
    first, width = np.inf, 0.0
    for k in keep:
        distance, _ = segment_distance(ray, starts[k], ends[k])
        inside = np.flatnonzero(distance <= radii[k])
        if len(inside) and t[inside[0]] < first:
            first, width = float(t[inside[0]]), float(radii[k])
    return (first, width) if np.isfinite(first) else None


def _seen(points: np.ndarray, close: np.ndarray, far: np.ndarray, r0: float) -> bool:
    """Whether a point (m) lies between :data:`SHELL` times ``r0`` (m) from the line ``close -> far`` (m), at least
    ``r0`` from both its ends."""
    length = float(np.linalg.norm(far - close))
    distance, t = segment_distance(points, close, far)
    return bool(np.any((distance >= SHELL[0] * r0) & (distance <= SHELL[1] * r0) &
                       (t * length >= r0) & ((1 - t) * length >= r0)))


def _fill(origin: np.ndarray, direction: np.ndarray, gap: float, r0: float, grown: float, limit: float,
          section_radii: float) -> list[tuple]:
    """Cylinders ``(start, end, radius)`` (m) from ``gap`` m back along the line to ``origin``, radii by the pipe
    model from ``r0`` (m) carrying ``grown`` m, at most ``limit`` m."""
    piece = section_radii * r0 if section_radii > 0 else gap
    count = max(1, int(np.ceil(gap / piece)))
    edges = np.linspace(gap, 0.0, count + 1)
    out = []
    for far, close in zip(edges[:-1], edges[1:]):
        middle = (far + close) / 2
        radius = min(limit, r0 * np.sqrt((grown + middle) / grown)) if grown > 0 else r0
        out.append(((origin - far * direction).tolist(), (origin - close * direction).tolist(), float(radius)))
    return out


def _growth_lengths(records: list[dict], index: dict) -> np.ndarray:
    """Length of each record's sections plus those of all its descendants, m (parents come first)."""
    own = np.array([sum(float(np.linalg.norm(np.subtract(e, s))) for s, e, _ in r["sections"]) for r in records])
    total = own.copy()
    for i in range(len(records) - 1, -1, -1):
        parent = records[i]["parent"]
        if parent >= 0:
            total[index[parent]] += total[i]
    return total


def _subtree(records: list[dict], index: dict, i: int) -> list[int]:
    """Indices of record ``i`` and all its descendants."""
    out, queue = [], [i]
    while queue:
        k = queue.pop()
        out.append(k)
        queue += [index[c] for c in records[k]["children"]]
    return out
