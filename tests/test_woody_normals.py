"""Multi-scale PCA normals and the noise-aware circle re-fit of STEP on noisy synthetic cylinders."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from woody import WoodyError
from woody.normals import multiscale_normals, pca_normals
from woody.step import Tuboid, refine_tuboid
from woody.synthetic import add_noise, sample_cylinders, straight_cylinder


def _angles_deg(estimated, truth):
    return np.degrees(np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", estimated, truth)), 0.0, 1.0)))


def test_multiscale_normals_of_a_noisy_cylinder_beat_the_fixed_neighbourhood():
    # Cylinder r = 0.3 m, 2 points per cm^2, Gaussian noise sigma = 1 cm. The 16 nearest neighbours span
    # r0 = sqrt(16 / (pi 2)) = 1.6 cm, about the noise: their smallest axis is nearly random. A plane fitted
    # to the N = pi R^2 rho points of a ball of radius R = 8 r0 = 12.8 cm (N ~ 1000) tilts with an s.d. of
    # 2 sigma / (R sqrt N) = 0.005 rad per axis, a median angle of about 0.3 deg; its sagitta on the cylinder,
    # R^2 / (2 r) = 2.7 cm, is symmetric about the point and leaves the normal's direction alone. Bound: 3 deg.
    cloud = sample_cylinders(straight_cylinder(0.3, 0.6), 2e4, seed=3)
    points = add_noise(cloud.points, 0.01, seed=4, kind="gaussian")
    new, noise = multiscale_normals(points, 16)
    assert np.median(_angles_deg(new, cloud.normals)) < 3.0
    assert np.median(_angles_deg(pca_normals(points, 16), cloud.normals)) > 3.0
    # sqrt(l0) of the chosen planes: the noise (1 cm) plus a little sagitta, not the cylinder's radius.
    assert 0.008 < np.median(noise) < 0.02


def test_multiscale_normals_of_a_clean_cloud_are_the_fixed_neighbourhood_ones():
    # Without noise the 16-neighbour plane has the least surface variation (the sagitta grows with the ball).
    cloud = sample_cylinders(straight_cylinder(0.1, 0.4), 2e4, seed=5)
    new, _ = multiscale_normals(cloud.points, 16)
    old = pca_normals(cloud.points, 16)
    assert np.mean(_angles_deg(new, old) < 0.01) > 0.99


def test_multiscale_normals_of_clean_thin_stems_mostly_keep_the_fixed_neighbourhood():
    # Two stems of radius 2.5 cm, axes 7 cm apart, seen from +x at 3 points per cm^2 with 2 mm of Gaussian noise
    # (a 0.08-deg scan of thin branches at 4 m). The 16 neighbours (r0 ~ 1.3 cm) see the noise and a sagitta of
    # r0^2 / (2 r) = 3 mm; a ball wider than a stem spreads its points over both stems, its thickness stops at the
    # stems' radius while its width grows, and its surface variation falls as noise would make it fall. Taking
    # any ball flatter than the point's plane moved 62-66 % of the normals and made 18-19 % of them more than
    # 30 deg worse (seeds 1, 5, 9); a ball must be twice as flat: 25-28 % and 8-10 %.
    stems = straight_cylinder(0.025, 0.6)
    stems = stems + [dict(c, start=[0.0, 0.07, 0.0], end=[0.0, 0.07, 0.6]) for c in stems]
    cloud = sample_cylinders(stems, 3e4, seed=1, view=(1.0, 0.0, 0.0))
    points = add_noise(cloud.points, 0.002, seed=2, kind="gaussian")
    old = pca_normals(points, 16)
    new, _ = multiscale_normals(points, 16)
    assert np.mean(_angles_deg(new, old) > 0.01) < 1 / 3
    assert np.mean(_angles_deg(new, cloud.normals) - _angles_deg(old, cloud.normals) > 30.0) < 0.12


def test_multiscale_normals_refuse_bad_levels():
    with pytest.raises(WoodyError, match="levels"):
        multiscale_normals(np.random.default_rng(0).normal(size=(50, 3)), levels=9)


def test_refit_accepts_residuals_at_the_measured_noise():
    # Uniform noise of A = 3 cm per coordinate: the radial residuals about the true circle are about U(-A, A),
    # median |.| = A / 2 = 1.5 cm, above the 1 cm radius cell, so a re-fit judged against the cell is refused
    # and the snake's radius (2 cm too large) stays; judged against the measured noise (s.d. A / sqrt 3 = 1.7
    # cm) it is kept, and the radius of the fit to ~1900 points per slab is within a few mm.
    cloud = sample_cylinders(straight_cylinder(0.5, 1.0), 3e4, seed=6)
    points = add_noise(cloud.points, 0.03, seed=7)
    z = np.linspace(0.1, 0.9, 9)
    tube = Tuboid(np.column_stack([np.zeros(9), np.zeros(9), z]), np.tile([0.0, 0.0, 1.0], (9, 1)),
                  np.full(9, 0.52))
    tree = cKDTree(points)
    _, noise = multiscale_normals(points, 16)
    assert np.all(refine_tuboid(tube, points, tree, 0.01).radii == 0.52)
    refined = refine_tuboid(tube, points, tree, 0.01, noise)
    assert np.all(np.abs(refined.radii - 0.5) < 0.005)
