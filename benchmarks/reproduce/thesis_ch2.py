"""Thesis ch.2 §3: the orchard ROP study (nine 9 cm pear leaves, three at each of 1.5, 3 and 5 m).

Each leaf is the ``single-leaf`` generator's procedural pear leaf, 9 cm
long, at 20 deg incidence with a wall 1 m behind (the built-in
``leaf-*m`` set-up), simulated with the ``faro-ls880`` preset at its
0.018 deg step. Per leaf (:func:`benchmarks.scoring.prepare_leaves`): the
points (returns with at least the scoring's power share from the leaf),
the outliers (farther from the true surfaces than ``max(3 sigma, 2 mm)``;
"true" outliers: 1 cm, the ch.2 subtle/true split), ROP (eq 3.1), the
precision (robust s.d. of the pure returns' distances to the true surface)
and RNS = precision / leaf length (eq 3.2).

The thesis' measured ROP values are kept out of the spec on purpose: the
published column stays empty and the rows test the published trends (ROP
rises with distance and falls with leaf size; point counts fall about as
1/d^2, tls-physics §6.4).
"""

from __future__ import annotations

import numpy as np

from benchmarks.generators import single_leaf
from benchmarks.reproduce.core import Row, register
from benchmarks.scoring import prepare_leaves
from tlssim.simulate import setup_from_section, simulate

DISTANCES_M = (1.5, 3.0, 5.0)
#: Leaf length of the ch.2 protocol, m (thesis ch.2 §3.1.3: leaves of about 9 cm).
LEAF_LENGTH_M = 0.09
SOURCE = "thesis ch.2 §3 (values held back)"


#: Leaf lengths of the size rows, m (the orchard's leaves averaged 6 cm, the study's were 9 cm: thesis ch.2 §3.1.3).
SIZES_M = (0.06, 0.09, 0.12)


def leaf_row(distance_m: float, seed: int, length_m: float = LEAF_LENGTH_M) -> dict:
    """Simulate one ch.2 leaf and measure its point count, ROP, precision and RNS.

    Parameters
    ----------
    distance_m : float
        Scanner-to-leaf distance, m.
    seed : int
        Seed of the leaf's shape and of the scan.
    length_m : float
        Leaf length, m.

    Returns
    -------
    dict
        ``points``, ``rop`` and ``rop_1cm`` (fractions), ``precision_mm`` and ``rns`` (dimensionless).
    """
    scene = single_leaf(distance_m=distance_m, incidence_deg=20.0, axis="horizontal", length_m=length_m,
                        seed=seed, background_gap_m=1.0)
    scan = simulate(scene, setup_from_section({**scene.scanner, "preset": "faro-ls880"}), seed=seed, progress=False)
    leaf = prepare_leaves(scene, scan)[0]
    far = np.abs(leaf.distance)
    precision = leaf.scan_stats["sigma_range_m"]
    return {"points": int(leaf.mask.sum()), "rop": float(np.mean(far > leaf.taus["auto"])),
            "rop_1cm": float(np.mean(far > leaf.taus["1cm"])), "precision_mm": 1e3 * precision,
            "rns": precision / length_m}


@register("ch2-rop", "Thesis ch.2 §3: ROP, point counts, precision and RNS of 9 cm leaves at 1.5, 3 and 5 m, and "
          "ROP against leaf size",
          description="Three procedural 9 cm pear leaves (seeds 0-2) at each distance, 20 deg incidence, wall 1 m "
                      "behind, faro-ls880 at 0.018 deg; outliers from the simulator's truth (distance to the true "
                      "surfaces) instead of the thesis' manual deletion in MeshLab; then leaves of 6, 9 and 12 cm "
                      "at 3 m (ROP falls with leaf size, the thesis' second trend; measured in round 11, seed 0: "
                      "34.9 / 25.1 / 19.6 %, and 43.3 % at 4.5 cm).",
          findings="The published ROP values are held back from the spec (so that the simulator is not tuned to "
                   "them): compare our column with the thesis by hand. Our outliers are defined from the truth "
                   "(tls-physics §7 item 10), the thesis' by eye, which misses 'subtle' outliers: expect ours "
                   "with the 2 mm rule above the thesis, and the 1 cm ('true' outliers) column nearer to it. "
                   "Precision: the range noise grows as the received power falls (sigma ~ A^-0.338, tls-physics "
                   "§6 item 11), and the near-range attenuator of the FARO model (A(d) = 1 / (1 + (3 m / d)^3), "
                   "tls-physics 7.5, a modelling assumption) makes A(d)/d^2 nearly flat from 1.5 to 3 m (0.049 "
                   "against 0.056: sigma 4 % higher at 1.5 m) before it falls at 5 m (0.033: sigma +19 %). So the "
                   "precision worsens from 3 to 5 m (full form, measured: 1.7 / 1.6 / 1.9 mm at 1.5 / 3 / 5 m, "
                   "the claim holds), not from 1.5 to 3 m: the quick form, which stops at 3 m, fails the claim "
                   "for that reason (modelling assumption, not a defect).")
def rop_study(quick: bool, seed: int) -> list[Row]:
    """Rows of the ROP study (per distance: mean over the leaves) and its trends.

    Parameters
    ----------
    quick : bool
        One leaf at 1.5 and 3 m only.
    seed : int
        Offset of the leaf seeds.
    """
    distances, seeds = ((1.5, 3.0), (seed,)) if quick else (DISTANCES_M, (seed, seed + 1, seed + 2))
    table = {d: [leaf_row(d, s) for s in seeds] for d in distances}
    rows = []
    means = {}
    for d, leaves in table.items():
        mean = {key: float(np.mean([leaf[key] for leaf in leaves])) for key in leaves[0]}
        means[d] = mean
        for key, quantity, unit, scale in (("points", "points per leaf", "points", 1),
                                           ("rop", "ROP (2 mm / 3 sigma rule)", "%", 100),
                                           ("rop_1cm", "ROP of true outliers (1 cm)", "%", 100),
                                           ("precision_mm", "precision", "mm", 1), ("rns", "RNS", "%", 100)):
            rows.append(Row(f"{d:g} m/{key}", quantity, unit, scale * mean[key], x=d, source=SOURCE,
                            note=f"mean of {len(leaves)} leaves"))
    near, far = distances[0], distances[-1]
    ratio = means[near]["points"] / means[far]["points"]
    expected = (far / near) ** 2
    rops = [means[d]["rop"] for d in distances]
    rows += [
        Row("ROP rises with distance", "claim", "%", 100 * rops[-1], source="thesis ch.2 conclusion",
            claim="ROP increases with distance", holds=bool(np.all(np.diff(rops) > 0)),
            note="ROP at each distance: " + ", ".join(f"{100 * r:.1f} %" for r in rops)),
        Row("point counts fall as 1/d^2", "points near / far", "ratio", ratio, expected, 0.25 * expected,
            "25 %: density falls as 1/d^2 (tls-physics §6 item 4 and A.4, a hard target for ratios); the outline "
            "pixels and the footprint blur make small leaves depart from it", "tls-physics A.4 [D]",
            note=f"{near:g} m against {far:g} m"),
        Row("precision worsens with distance", "claim", "mm", means[far]["precision_mm"],
            source="thesis ch.1 Table 1 (distance: precision falls)", claim="distance precision falls with distance",
            holds=bool(means[far]["precision_mm"] > means[near]["precision_mm"]),
            note="precision at each distance: " + ", ".join(f"{means[d]['precision_mm']:.2f} mm" for d in distances)
                 + " (the near-range attenuator keeps the received power, and so the noise, nearly flat up to 3 m)"),
    ]
    sizes = (SIZES_M[0], SIZES_M[-1]) if quick else SIZES_M
    by_size = [float(np.mean([leaf_row(3.0, s, length)["rop"] for s in seeds])) for length in sizes]
    rows += [Row(f"3 m/{100 * length:g} cm leaf/rop", "ROP against leaf size, 3 m", "%", 100 * rop, x=100 * length,
                 source=SOURCE, note=f"mean of {len(seeds)} leaves") for length, rop in zip(sizes, by_size)]
    rows.append(Row("ROP falls with leaf size", "claim", "%", 100 * by_size[-1], source="thesis ch.2 conclusion",
                    claim="ROP decreases as the leaf grows (ours: leaves of "
                          + " / ".join(f"{100 * length:g}" for length in sizes) + " cm at 3 m)",
                    holds=bool(np.all(np.diff(by_size) < 0)),
                    note="ROP: " + " / ".join(f"{100 * r:.1f}" for r in by_size) + " %"))
    return rows
