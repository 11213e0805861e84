"""Point-cloud readers (NPZ, tlssim scan NPZ, PLY, LAS, E57, PTX, ASCII), normals and synthetic sampling."""

import numpy as np
import pytest

from tlssim.pattern import ScannerPose
from tlssim.scan import Scan, write_npz, write_ply_points
from woody import WoodyError, pca_normals, read_cloud
from woody.synthetic import add_noise, sample_cylinders, straight_cylinder

POINTS = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [-1.5, 0.25, 2.0], [0.5, -0.5, 1.0]])


def test_plain_npz_with_normals_and_scanner_position(tmp_path):
    normals = np.tile([0.0, 0.0, 2.0], (4, 1))
    path = write_npz(tmp_path / "c.npz", {"points": POINTS, "normals": normals, "scanner_position": np.ones(3)})
    cloud = read_cloud(path)
    assert np.array_equal(cloud.points, POINTS)
    assert np.allclose(cloud.normals, [0.0, 0.0, 1.0])  # normalised
    assert np.array_equal(cloud.viewpoints, np.ones((4, 3)))


def test_tlssim_scan_npz_gives_valid_points_scanner_and_truth_normals(tmp_path):
    xyz = np.arange(18, dtype=float).reshape(2, 3, 3)
    rng = np.array([[1.0, np.nan, 2.0], [3.0, 4.0, np.nan]])
    xyz[np.isnan(rng)] = np.nan
    truth_normal = np.zeros((2, 3, 3))
    truth_normal[..., 0] = 1.0
    scan = Scan(range=rng, intensity=np.ones((2, 3), np.float32), theta=np.zeros((2, 3)), psi=np.zeros((2, 3)),
                xyz=xyz, pose=ScannerPose(np.array([5.0, 6.0, 7.0]), np.eye(3)),
                truth_range=rng, truth_id=np.zeros((2, 3), np.int32), mixed_fraction=np.zeros((2, 3)),
                incidence=np.zeros((2, 3)), truth_normal=truth_normal)
    cloud = read_cloud(scan.save(tmp_path / "scan.npz"))
    assert np.array_equal(cloud.points, xyz[np.isfinite(rng)])
    assert np.array_equal(cloud.viewpoints[0], [5.0, 6.0, 7.0]) and len(cloud.viewpoints) == 4
    assert np.allclose(cloud.normals, [1.0, 0.0, 0.0])


def test_ply_with_normals(tmp_path):
    columns = [(a, "<f8", POINTS[:, i]) for i, a in enumerate("xyz")]
    columns += [(a, "<f4", np.full(4, v)) for a, v in (("nx", 0.0), ("ny", 1.0), ("nz", 0.0))]
    cloud = read_cloud(write_ply_points(tmp_path / "c.ply", columns))
    assert np.allclose(cloud.points, POINTS) and np.allclose(cloud.normals, [0.0, 1.0, 0.0])
    assert cloud.viewpoints is None


def test_las(tmp_path):
    import laspy

    las = laspy.create(point_format=0, file_version="1.2")
    las.header.scales = [0.001, 0.001, 0.001]
    las.x, las.y, las.z = POINTS[:, 0], POINTS[:, 1], POINTS[:, 2]
    las.write(tmp_path / "c.las")
    assert np.allclose(read_cloud(tmp_path / "c.las").points, POINTS, atol=1e-3)


def test_e57_scans_are_read_in_world_coordinates_with_their_scanner_positions(tmp_path):
    import pye57

    path = str(tmp_path / "c.e57")
    e57 = pye57.E57(path, mode="w")
    for shift in (0.0, 10.0):  # points in each scan's own frame, placed by its pose
        data = {"cartesianX": POINTS[:, 0], "cartesianY": POINTS[:, 1], "cartesianZ": POINTS[:, 2]}
        e57.write_scan_raw(data, translation=np.array([shift, 0.0, 1.5]))
    e57.close()
    cloud = read_cloud(path)
    assert np.allclose(cloud.points[:4], POINTS + [0.0, 0.0, 1.5])
    assert np.allclose(cloud.points[4:], POINTS + [10.0, 0.0, 1.5])
    assert np.allclose(cloud.viewpoints[0], [0.0, 0.0, 1.5]) and np.allclose(cloud.viewpoints[-1], [10.0, 0.0, 1.5])


@pytest.mark.parametrize("name, content, message", [
    ("x.foo", b"1 2 3", "unknown point-cloud format"),
    ("x.xyz", b"1 2\n3 4\n", "three columns"),
    ("x.csv", b"x,y,z\n1,2,3\n4,five,6\n", "line 3"),
    ("x.txt", "é".encode("latin-1"), "ASCII"),
    ("x.npz", b"not a zip", "not a readable NPZ"),
    ("x.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n", "x, y, z"),
    ("x.las", b"garbage", "LAS"),
    ("x.e57", b"garbage", "E57"),
])
def test_malformed_files_name_the_file_and_the_problem(tmp_path, name, content, message):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(WoodyError, match=message) as info:
        read_cloud(path)
    assert name in str(info.value)


def test_ascii_ply_with_normals(tmp_path):
    path = tmp_path / "a.ply"
    rows = "".join(f"{x} {y} {z} 0 0 1 7\n" for x, y, z in POINTS)
    path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                    "property float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nend_header\n" + rows)
    cloud = read_cloud(path)
    assert np.allclose(cloud.points, POINTS) and np.allclose(cloud.normals, [0.0, 0.0, 1.0])


@pytest.mark.parametrize("name, text", [
    ("c.xyz", "\n".join(" ".join(map(str, p)) for p in POINTS)),
    ("c.csv", "// X,Y,Z,intensity\n" + "\n".join(",".join(map(str, p)) + ",0.5" for p in POINTS)),
    ("c.pts", "4\n" + "\n".join("\t".join(map(str, p)) + " 12 200 10 10" for p in POINTS)),
    ("c.txt", "intensity;x;y;z;nx;ny;nz\n" + "\n".join(f"1;{x};{y};{z};0;2;0" for x, y, z in POINTS)),
])
def test_ascii_columns_with_or_without_a_header(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text + "\n")
    cloud = read_cloud(path)
    assert np.allclose(cloud.points, POINTS)
    assert (cloud.normals is None) == (name != "c.txt")
    if cloud.normals is not None:
        assert np.allclose(cloud.normals, [0.0, 1.0, 0.0])


def test_rotated_unstructured_e57_and_tlssim_las_and_ptx_round_trips(tmp_path):
    import pye57

    from tlssim.formats import export_scan

    path = str(tmp_path / "s.e57")
    with pye57.E57(path, mode="w") as e57:  # a scan turned 90 deg about z (quaternion w, x, y, z)
        e57.write_scan_raw({"cartesianX": POINTS[:, 0], "cartesianY": POINTS[:, 1], "cartesianZ": POINTS[:, 2]},
                           rotation=np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)]),
                           translation=np.array([1.0, 0.0, 0.0]))
    cloud = read_cloud(path)
    assert np.allclose(cloud.points, np.column_stack([1.0 - POINTS[:, 1], POINTS[:, 0], POINTS[:, 2]]), atol=1e-6)
    xyz = np.arange(18, dtype=float).reshape(2, 3, 3) + 1.0
    scan = Scan(range=np.linalg.norm(xyz - [5.0, 6.0, 7.0], axis=-1), intensity=np.ones((2, 3), np.float32),
                theta=np.zeros((2, 3)), psi=np.full((2, 3), np.pi / 2), xyz=xyz,
                pose=ScannerPose(np.array([5.0, 6.0, 7.0]), np.eye(3)))
    for suffix in (".las", ".ptx"):
        cloud = read_cloud(export_scan(scan, tmp_path / f"s{suffix}"))
        # LAS holds the returns column by column, as the scanner records them (and a tiled scan streams them)
        expected = xyz.transpose(1, 0, 2) if suffix == ".las" else xyz
        assert np.allclose(cloud.points, expected.reshape(-1, 3), atol=1e-4), suffix
        assert np.allclose(cloud.viewpoints, [5.0, 6.0, 7.0]), suffix


def test_missing_file_and_bad_arrays(tmp_path):
    with pytest.raises(WoodyError, match="no such"):
        read_cloud(tmp_path / "none.npz")
    with pytest.raises(WoodyError, match="NaN"):
        read_cloud(write_npz(tmp_path / "nan.npz", {"points": np.array([[0.0, np.nan, 1.0]])}))
    with pytest.raises(WoodyError, match="'points'"):
        read_cloud(write_npz(tmp_path / "other.npz", {"values": np.zeros(3)}))


def test_pca_normals_face_the_scanner_and_are_radial_on_a_cylinder():
    cloud = sample_cylinders(straight_cylinder(0.2, 0.5), 2e4, seed=1, arc_deg=90)
    normals = pca_normals(cloud.points, 16, viewpoints=(5.0, 0.0, 0.25))
    assert np.percentile(np.abs(np.einsum("ij,ij->i", normals, cloud.normals)), 5) > 0.99
    assert (np.einsum("ij,ij->i", normals, cloud.normals) > 0).all()  # outward: the scanner is outside
    with pytest.raises(WoodyError, match="too few"):
        pca_normals(cloud.points[:5], 16)


def test_synthetic_sampling_density_normals_and_determinism():
    cylinders = straight_cylinder(0.1, 1.0)
    a = sample_cylinders(cylinders, 1e4, seed=5)
    b = sample_cylinders(cylinders, 1e4, seed=5)
    assert a.points.tobytes() == b.points.tobytes()
    area = 2 * np.pi * 0.1 * 1.0
    assert len(a.points) == pytest.approx(1e4 * area, rel=0.05)
    assert np.allclose(np.hypot(a.points[:, 0], a.points[:, 1]), 0.1)
    assert np.allclose(a.normals[:, :2] * 0.1, a.points[:, :2])
    half = sample_cylinders(cylinders, 1e4, seed=5, view=(1.0, 0.0, 0.0))
    assert (half.points[:, 0] > 0).all() and len(half.points) == pytest.approx(len(a.points) / 2, rel=0.1)
    noisy = add_noise(a.points, 0.01, seed=1)
    assert np.abs(noisy - a.points).max() <= 0.01
