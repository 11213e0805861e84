"""Hidden stretches of a limb (woody.gaps): a limb whose stretch next to the stem left no points is filled along
its line; twigs beside the gap are not joined to wood they do not grow from."""

import numpy as np

from woody import follow_cylinders
from woody.gaps import extend_over_strips, fill_gaps
from woody.geometry import segment_distance
from woody.synthetic import polyline_cylinders, sample_cylinders, straight_cylinder

#: The limb: from the stem (5 cm radius, 1.2 m) at 0.5 m height, 40 deg from the vertical, 0.9 m, radius 2 -> 1.5 cm;
#: its points from 0.1 to 0.45 m along it are removed but for :data:`THROUGH` of them (leaves let a few pulses through).
LIMB_BASE = np.array([0.0, 0.0, 0.5])
LIMB_AXIS = np.array([np.sin(np.radians(40)), 0.0, np.cos(np.radians(40))])
HIDDEN = (0.1, 0.45)
THROUGH = 0.01


def _limb() -> list[dict]:
    return polyline_cylinders(np.array([LIMB_BASE, LIMB_BASE + 0.9 * LIMB_AXIS]), np.array([0.02, 0.015]),
                              first_id=1, parent=0, order=2, branch=1)


def _inside(cylinders: list[dict], start, end, samples: int = 24) -> np.ndarray:
    """Whether each of ``samples`` points along ``start -> end`` (m) lies inside one of the ``cylinders``."""
    points = np.asarray(start) + np.linspace(0.0, 1.0, samples)[:, None] * (np.asarray(end) - np.asarray(start))
    inside = np.zeros(samples, bool)
    for c in cylinders:
        distance, t = segment_distance(points, np.asarray(c["start"]), np.asarray(c["end"]))
        inside |= (distance <= c["radius_m"]) & (t > 0) & (t < 1)
    return inside


def test_a_limbs_hidden_stretch_is_filled_along_its_line_with_its_radius():
    cloud = sample_cylinders(straight_cylinder(0.05, 1.2) + _limb(), 2e4, seed=2)
    along = (cloud.points - LIMB_BASE) @ LIMB_AXIS
    through = np.random.default_rng(2).random(len(cloud.points)) < THROUGH
    hidden = (cloud.labels == 1) & (along > HIDDEN[0]) & (along < HIDDEN[1]) & ~through
    result = follow_cylinders(cloud.points[~hidden])
    cylinders = result.cylinders()
    lo, hi = LIMB_BASE + (HIDDEN[0] + 0.02) * LIMB_AXIS, LIMB_BASE + (HIDDEN[1] - 0.02) * LIMB_AXIS
    assert _inside(cylinders, lo, hi).all()  # without the fill: none of it
    across = [c["radius_m"] for c in cylinders if segment_distance(
        ((np.asarray(c["start"]) + np.asarray(c["end"])) / 2)[None], lo, hi)[0][0] < 0.01]
    assert across and all(0.015 <= r <= 0.025 for r in across)  # the limb's 1.9-2 cm there, not the stem's 5 cm


def test_twigs_beside_the_gap_are_not_joined_to_wood_they_do_not_grow_from():
    # Twig A leaves the limb above the gap; its line extended back runs 8 cm beside the hidden stretch into the
    # stem. Twig B's first 30 cm are hidden (a few pulses through): 6 cm of it are seen, a piece too short to carry
    # its line to the stem.
    a_start = LIMB_BASE + 0.7 * LIMB_AXIS
    a_axis = (a_start - np.array([0.0, 0.0, 0.75])) / np.linalg.norm(a_start - np.array([0.0, 0.0, 0.75]))
    b_start, b_axis = np.array([0.0, 0.05, 0.3]), np.array([0.0, 0.8, 0.6])
    twigs = polyline_cylinders(np.array([a_start, a_start + 0.25 * a_axis]), np.array([0.008, 0.008]), first_id=2,
                               parent=1, order=3, branch=2) + \
        polyline_cylinders(np.array([b_start, b_start + 0.36 * b_axis]), np.array([0.008, 0.008]), first_id=3,
                           parent=0, order=2, branch=3)
    cloud = sample_cylinders(straight_cylinder(0.05, 1.2) + _limb() + twigs, 2e4, seed=3)
    along = (cloud.points - LIMB_BASE) @ LIMB_AXIS
    through = np.random.default_rng(3).random(len(cloud.points)) < THROUGH
    hidden = (((cloud.labels == 1) & (along > HIDDEN[0]) & (along < HIDDEN[1])) |
              ((cloud.labels == 3) & ((cloud.points - b_start) @ b_axis < 0.3))) & ~through
    cylinders = follow_cylinders(cloud.points[~hidden]).cylinders()
    assert _inside(cylinders, LIMB_BASE + 0.12 * LIMB_AXIS, LIMB_BASE + 0.43 * LIMB_AXIS).all()
    assert not _inside(cylinders, a_start - 0.1 * a_axis, np.array([0.0, 0.0, 0.75]) + 0.06 * a_axis).any()
    assert not _inside(cylinders, b_start + 0.06 * b_axis, b_start + 0.28 * b_axis).any()


def _records(first_radius: float, gap: float, carried: float) -> tuple[list[dict], np.ndarray]:
    """A stem record (5 cm, z 0-1 m) and a branch record along +x at 0.5 m height whose first section starts
    ``gap`` m from the stem's surface: sections of 4 radii over ``carried`` m; and points on the branch's surface
    in the gap, one per 4 cm."""
    count = max(1, int(round(carried / (4 * first_radius))))
    edges = 0.05 + gap + np.linspace(0.0, carried, count + 1)
    sections = [([a, 0.0, 0.5], [b, 0.0, 0.5], first_radius) for a, b in zip(edges[:-1], edges[1:])]
    x = np.arange(0.07, 0.05 + gap - 0.01, 0.04)
    seen = np.column_stack([x, np.full(len(x), first_radius), np.full(len(x), 0.5)])
    return [{"id": 0, "parent": -1, "children": [1], "start": [0, 0, 0], "sections": [([0, 0, 0], [0, 0, 1], 0.05)],
             "reliable": [True]},
            {"id": 1, "parent": 0, "children": [], "start": sections[0][0], "sections": sections,
             "reliable": [True] * count}], seen


def test_the_fill_follows_the_pipe_model_and_needs_evidence_on_both_sides_of_the_gap():
    records, seen = _records(0.01, 0.3, 0.6)
    assert fill_gaps(records, seen, 1.0, 4.0) == 1
    filled = records[1]["sections"][:8]  # 0.3 m in pieces of 4 cm
    assert abs(filled[0][0][0] - 0.05) <= 0.005  # from the stem's surface (the ray is sampled every r0 / 2)
    radii = [r for _, _, r in filled]
    assert radii == sorted(radii, reverse=True)  # thicker towards the stem
    assert abs(radii[0] - 0.01 * np.sqrt((0.6 + 0.28) / 0.6)) < 0.001  # pipe model: r0 sqrt((G + t) / G)
    assert records[1]["reliable"][:8] == [True] * 8 and records[1]["start"] == list(filled[0][0])
    # A short piece, out of reach, no gap, a gap the scan saw empty.
    for gap, carried, reach, empty in ((0.3, 0.2, 1.0, False), (0.3, 0.6, 0.2, False), (0.02, 0.6, 1.0, False),
                                       (0.3, 0.6, 1.0, True)):
        records, seen = _records(0.01, gap, carried)
        sections = list(records[1]["sections"])
        assert fill_gaps(records, seen[:0] if empty else seen, reach, 4.0) == 0
        assert records[1]["sections"] == sections


def test_a_first_radius_fitted_near_zero_is_judged_at_once():
    # A first section fitted at 1e-12 m (collinear points): its ray back to the stem would be sampled every
    # 5e-13 m (6e11 samples); no point lies on a line that thin, so nothing is filled.
    records, seen = _records(0.01, 0.3, 0.6)
    start, end, _ = records[1]["sections"][0]
    records[1]["sections"][0] = (start, end, 1e-12)
    sections = list(records[1]["sections"])
    assert fill_gaps(records, seen, 1.0, 4.0) == 0
    assert records[1]["sections"] == sections


def test_a_limbs_unresolved_pieces_before_its_first_resolved_section_are_filled_over():
    # Leaves split a limb's base into strips: growth followed it as thin pieces the points do not resolve (2 mm
    # here), then resolved it (1 cm). The line back from the first resolved section is filled to the stem, and
    # the unresolved pieces on it are replaced by the fill.
    records, seen = _records(0.01, 0.3, 0.6)
    resolved = records[1]["sections"][2:]
    records[1]["sections"][:2] = [(a, b, 0.002) for a, b, _ in records[1]["sections"][:2]]
    records[1]["reliable"][:2] = [False, False]
    assert fill_gaps(records, seen, 1.0, 4.0) == 1
    sections = records[1]["sections"]
    assert sections[-len(resolved):] == resolved and all(records[1]["reliable"])
    filled = sections[:-len(resolved)]
    assert abs(filled[0][0][0] - 0.05) <= 0.005 and abs(filled[-1][1][0] - resolved[0][0][0]) < 1e-9
    assert all(r >= 0.01 for _, _, r in filled)  # the pipe model from the resolved section, not the 2 mm pieces
    # A piece that runs back towards the stem is no stretch of the limb: the branch is left alone.
    records, seen = _records(0.01, 0.3, 0.6)
    records[1]["sections"][:2] = [(b, a, 0.002) for a, b, _ in records[1]["sections"][:2]]
    records[1]["reliable"][:2] = [False, False]
    sections = list(records[1]["sections"])
    assert fill_gaps(records, seen, 1.0, 4.0) == 0
    assert records[1]["sections"] == sections
    # Unresolved pieces that start on the stem's surface leave no gap to fill: the branch is left alone.
    records, seen = _records(0.01, 0.0, 0.6)
    records[1]["reliable"][:1] = [False]
    sections = list(records[1]["sections"])
    assert fill_gaps(records, seen, 1.0, 4.0) == 0
    assert records[1]["sections"] == sections


def _strip_records(offset: float, strip_radius: float, holes: tuple = ()) -> list[dict]:
    """A root record far off, and a limb of 2 cm radius along +z from z = 0: its resolved part (z 0.5-0.98) a child of
    a chain of strip records (z 0.1-0.5, 2 cm pieces of ``strip_radius``, unresolved, their axes ``offset`` m off
    the limb's along +x, but those whose index is in ``holes``)."""
    records = [{"id": 0, "parent": -1, "children": [1], "start": [1.0, 1.0, -1.0],
                "sections": [([1.0, 1.0, -1.0], [1.0, 1.0, 0.0], 0.05)], "reliable": [True]}]
    edges = [k for k in np.arange(0.1, 0.5001, 0.02) if int(round((k - 0.1) / 0.02)) not in holes]
    chain = [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b - a < 0.03]
    for k, (a, b) in enumerate(chain):
        records.append({"id": k + 1, "parent": k, "children": [k + 2], "start": [offset, 0.0, a],
                        "sections": [([offset, 0.0, a], [offset, 0.0, b], strip_radius)], "reliable": [False]})
    top = len(records)
    records[-1]["children"] = [top]
    records.append({"id": top, "parent": top - 1, "children": [], "start": [0.0, 0.0, 0.5],
                    "sections": [([0.0, 0.0, z], [0.0, 0.0, z + 0.08], 0.02)
                                 for z in (0.5, 0.58, 0.66, 0.74, 0.82, 0.9)],
                    "reliable": [True] * 6})
    return records


def _surface(radius: float) -> np.ndarray:
    """Points at ``radius`` m from the z axis, 80 deg of arc facing +x, every 5 mm of z from 0.1 to 0.98 m."""
    z, angle = np.meshgrid(np.arange(0.1, 0.98, 0.005), np.radians(np.arange(-40, 41, 10)))
    return np.column_stack([radius * np.cos(angle.ravel()), radius * np.sin(angle.ravel()), z.ravel()])


def test_a_limb_is_extended_back_over_the_strips_of_its_surface():
    # The strips' axes lie on the limb's surface (one radius off its axis) and 3 mm wide: the limb is filled back
    # from its resolved part along its own axis, at the pipe model's radii from its own (it carries 0.48 m), as far
    # as the strips reach (z 0.1).
    records = _strip_records(0.02, 0.003)
    assert extend_over_strips(records, _surface(0.02), 1.0, 4.0) == 1
    top = records[-1]
    start, end, radius = top["sections"][0]
    assert np.allclose(start, [0.0, 0.0, 0.1], atol=1e-9) and all(top["reliable"])
    filled = [s for s in top["sections"] if s[1][2] <= 0.5 + 1e-9]
    assert len(filled) == 5 and all(abs(a[0]) < 1e-9 and abs(e[0]) < 1e-9 for a, e, _ in filled)
    assert np.isclose(filled[0][2], 0.02 * np.sqrt((0.48 + 0.36) / 0.48))  # r0 sqrt((G + t) / G), t mid-piece
    assert [r for _, _, r in filled] == sorted((r for _, _, r in filled), reverse=True)
    assert np.isclose(sum(e[2] - a[2] for a, e, _ in filled), 0.4)


def test_no_extension_over_pieces_off_the_limb_as_wide_as_it_across_a_break_or_off_the_points():
    # Pieces 2 radii off the line are no strips of it, nor pieces as wide as half the limb; nor is a stretch whose
    # points lie 0.7 of its radius from its line (a first section fitted too wide) or none at all; a break of 12 cm
    # (over 4 radii) in the strips, from z 0.28 to 0.40, ends the stretch at it.
    for offset, radius, points in ((0.04, 0.003, _surface(0.02)), (0.02, 0.011, _surface(0.02)),
                                   (0.02, 0.003, _surface(0.014)), (0.02, 0.003, _surface(0.02)[:0])):
        records = _strip_records(offset, radius)
        assert extend_over_strips(records, points, 1.0, 4.0) == 0
        assert records[-1]["sections"][0][0][2] == 0.5
    records = _strip_records(0.02, 0.003, holes=(10, 11, 12, 13, 14))
    assert extend_over_strips(records, _surface(0.02), 1.0, 4.0) == 1
    assert np.isclose(records[-1]["sections"][0][0][2], 0.40)
