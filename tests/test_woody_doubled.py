"""Wood counted twice (woody.merge.drop_doubled): a section inside another branch's wood goes, a child that leaves
its parent stays, and the records stay a tree."""

import numpy as np

from woody.merge import _inside_share, drop_doubled


def _record(rid: int, parent: int, children: list[int], sections: list[tuple]) -> dict:
    sections = [(list(map(float, a)), list(map(float, e)), float(r)) for a, e, r in sections]
    return {"id": rid, "parent": parent, "children": children, "start": sections[0][0], "end": sections[-1][1],
            "sections": sections, "reliable": [True] * len(sections)}


def test_inside_share_counts_the_samples_inside_other_cylinders():
    start, end = np.zeros(3), np.array([0.0, 0.0, 1.0])
    coaxial = (np.array([[0.0, 0.0, -0.1]]), np.array([[0.0, 0.0, 1.1]]))
    assert abs(_inside_share(start, end, 0.05, *coaxial, np.array([0.1])) - 1.0) < 1e-12  # thin inside wide
    assert abs(_inside_share(start, end, 0.05, *coaxial, np.array([0.01])) - 0.1) < 1e-12  # only the axis samples
    # the first 0.4 m of it covered: the samples at 0.1 and 0.3 of its length, two fifths
    lower = (np.array([[0.0, 0.0, -0.1]]), np.array([[0.0, 0.0, 0.4]]))
    assert abs(_inside_share(start, end, 0.05, *lower, np.array([0.1])) - 0.4) < 1e-12
    side = (np.array([[0.3, 0.0, 0.0]]), np.array([[0.3, 0.0, 1.0]]))  # a parallel limb 0.3 m away
    assert _inside_share(start, end, 0.05, *side, np.array([0.1])) == 0.0


def test_a_branch_grown_inside_another_is_dropped_and_its_child_and_points_go_to_its_parent():
    stem = _record(0, -1, [1, 2], [((0, 0, 0), (0, 0, 1), 0.1), ((0, 0, 1), (0, 0, 2), 0.09)])
    twin = _record(1, 0, [3], [((0.02, 0, 0.8), (0.02, 0, 1.2), 0.05), ((0.02, 0, 1.2), (0.02, 0, 1.6), 0.05)])
    limb = _record(2, 0, [], [((0.1, 0, 0.5), (0.5, 0, 0.8), 0.03)])  # leaves the stem: stays
    twig = _record(3, 1, [], [((0.09, 0, 1.4), (0.4, 0, 1.7), 0.01)])
    records = [stem, twin, limb, twig]
    labels = np.array([0, 1, 1, 2, 3, -1])
    assert drop_doubled(records, labels) == 2
    assert [r["id"] for r in records] == [0, 1, 2]
    assert [len(r["sections"]) for r in records] == [2, 1, 1]
    assert records[0]["children"] == [1, 2] and records[2]["parent"] == 0  # the twig now grows from the stem
    assert records[1]["sections"][0][2] == 0.03
    assert labels.tolist() == [0, 0, 0, 1, 2, -1]


def test_of_two_twins_the_younger_goes_and_a_roots_first_section_stays():
    root = _record(0, -1, [1], [((0, 0, 0), (0, 0, 0.5), 0.05), ((0, 0, 0.5), (0, 0, 1), 0.05)])
    twin = _record(1, 0, [], [((0.005, 0, 0), (0.005, 0, 0.5), 0.05), ((0.005, 0, 0.5), (0.005, 0, 1), 0.05)])
    records = [root, twin]
    assert drop_doubled(records, np.array([0, 1])) == 2
    assert len(records) == 1 and len(records[0]["sections"]) == 2
    # the same twin as the root's only other record, and the root's own second section inside it: it goes, the
    # first stays
    root = _record(0, -1, [1], [((0, 0, 0), (0, 0, 0.5), 0.05), ((0, 0, 0.5), (0, 0, 1), 0.04)])
    wide = _record(1, 0, [], [((0.005, 0, 0.45), (0.005, 0, 1.05), 0.06)])
    records = [root, wide]
    assert drop_doubled(records, np.array([0, 1])) == 1
    assert [len(r["sections"]) for r in records] == [1, 1]
