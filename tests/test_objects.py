"""Objects: built-ins, polygons from vertices and CSV, meshes from files (clean and messy),
analytic shapes; outward normals, area-uniform sampling, one-sentence errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from grasp_jax import objects
from grasp_jax.objects import (
    BUILTIN_NAMES, Box, Cylinder, Ellipsoid, GraspObject, Mesh, ObjectError, Polygon, Sphere,
)

RNG = np.random.default_rng


def winding_number(triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Generalized winding number of ``points: (m, 3)`` w.r.t. ``triangles: (F, 3, 3)``
    (Van Oosterom-Strackee solid angles): 1 inside a closed outward surface, 0 outside."""
    out = []
    for q in np.array_split(points, max(1, len(points) // 8)):
        a, b, c = np.moveaxis(triangles[None] - q[:, None, None], 2, 0)
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("mfi,mfi->mf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("mfi,mfi->mf", a, b) * lc + np.einsum("mfi,mfi->mf", b, c) * la
               + np.einsum("mfi,mfi->mf", c, a) * lb)
        out.append(np.arctan2(det, den).sum(1) / (2 * np.pi))
    return np.concatenate(out)


def assert_outward_3d(obj, count=24, seed=0):
    points, normals = obj.sample_surface(count, RNG(seed))
    eps = 1e-6 * obj.radius
    tri = np.asarray(obj.mesh.triangles)
    assert np.allclose(winding_number(tri, points + eps * normals), 0.0, atol=1e-3)
    assert np.allclose(winding_number(tri, points - eps * normals), 1.0, atol=1e-3)


def assert_outward_2d(poly, count=200, seed=0):
    points, normals = poly.sample_surface(count, RNG(seed))
    eps = 1e-7 * poly.radius
    assert not poly.contains(points + eps * normals).any()
    assert poly.contains(points - eps * normals).all()


def assert_unit(normals):
    assert np.allclose(np.linalg.norm(normals, axis=-1), 1.0)


# ---------------------------------------------------------------------------------- built-ins


@pytest.mark.parametrize("name", BUILTIN_NAMES)
def test_builtin_loads(name):
    obj = objects.load(name)
    assert isinstance(obj, GraspObject)
    assert obj.name == name and obj.dim in (2, 3) and obj.warnings == ()
    assert obj.center.shape == (obj.dim,) and np.isfinite(obj.center).all() and obj.radius > 0
    centroids, normals = obj.facets()
    assert centroids.shape == normals.shape and centroids.shape[1] == obj.dim
    assert_unit(normals)
    points, normals = obj.sample_surface(50, RNG(0))
    assert points.shape == normals.shape == (50, obj.dim)
    assert_unit(normals)
    if obj.dim == 3:
        assert obj.mesh.is_watertight and obj.mesh.is_volume
    else:
        assert_outward_2d(obj)


@pytest.mark.parametrize("name, faces", [("glass", 9486), ("part", 2824)])
def test_paper_sized_meshes(name, faces):
    obj = objects.load(name)
    assert abs(len(obj.mesh.faces) - faces) < 0.05 * faces
    assert obj.mesh.is_watertight and obj.mesh.is_winding_consistent
    assert np.allclose(obj.center, obj.mesh.center_mass)
    assert np.isclose(obj.radius, np.linalg.norm(obj.mesh.vertices - obj.center, axis=1).max())
    assert_outward_3d(obj)


def test_part_has_holes():
    # genus: V - E + F = 2 - 2g; four through holes make genus 4
    mesh = objects.part().mesh
    assert mesh.euler_number == 2 - 2 * 4


def test_glass_is_hollow():
    glass = objects.glass()
    axis = np.array([[0.0, 0.0, 0.05], [0.0, 0.0, 0.004], [0.0, 0.0, 0.2]])
    assert np.allclose(winding_number(np.asarray(glass.mesh.triangles), axis), [0.0, 1.0, 0.0], atol=1e-6)


def test_load_errors(tmp_path):
    with pytest.raises(ObjectError, match="glass, part"):
        objects.load("teapot")
    with pytest.raises(ObjectError, match="neither a file"):
        objects.load(tmp_path / "missing.obj")
    with pytest.raises(ObjectError, match="is a directory"):
        objects.load(tmp_path)


def test_load_polygon_with_hole_files(tmp_path):
    (tmp_path / "square.csv").write_text("0,0\n2,0\n2,2\n0,2\n")
    (tmp_path / "hole.csv").write_text("x,y\n0.5,0.5\n1.5,0.5\n1.5,1.5\n0.5,1.5\n")
    poly = objects.load(tmp_path / "square.csv", holes=[tmp_path / "hole.csv"])
    assert len(poly.rings) == 2 and np.isclose(poly.area, 3.0)
    assert_outward_2d(poly)
    with pytest.raises(ObjectError, match="only be cut from a polygon"):
        objects.load("glass", holes=[tmp_path / "hole.csv"])
    with pytest.raises(ObjectError, match="hole .*missing.csv.*not found"):
        objects.load(tmp_path / "square.csv", holes=[tmp_path / "missing.csv"])


# ----------------------------------------------------------------------------------- polygons


def test_polygon_orientation_and_reversal():
    ring = np.array([[0, 0], [3, 0], [3, 2], [1, 1], [0, 2]], float)  # non-convex
    a, b = Polygon.from_vertices(ring), Polygon.from_vertices(ring[::-1])
    assert Polygon.from_vertices(np.vstack([ring, ring[:1]])).rings[0].shape == (5, 2)
    ca, na = a.facets()
    cb, nb = b.facets()
    order_a, order_b = np.lexsort(ca.T), np.lexsort(cb.T)
    assert np.allclose(ca[order_a], cb[order_b]) and np.allclose(na[order_a], nb[order_b])
    assert_outward_2d(a)
    assert np.isclose(a.area, 6.0 - 1.5)


def test_polygon_with_hole():
    square = [[0, 0], [4, 0], [4, 4], [0, 4]]
    hole = [[0.5, 0.5], [1.5, 0.5], [1.5, 1.5], [0.5, 1.5]]  # counter-clockwise: gets reversed
    poly = Polygon.from_vertices(square, [hole])
    assert np.isclose(poly.area, 15.0)
    assert np.allclose(poly.center, (16 * 2 - 1 * 1) / 15)
    assert np.isclose(poly.radius, np.hypot(31 / 15, 31 / 15))
    assert poly.contains([[3, 3]]).all() and not poly.contains([[1, 1]]).any()
    centroids, normals = poly.facets()
    inner = np.all((centroids > 0.4) & (centroids < 1.6), axis=1)
    # hole normals point into the hole, towards its centre (1, 1)
    assert np.all(np.einsum("ij,ij->i", normals[inner], [1.0, 1.0] - centroids[inner]) > 0)
    assert_outward_2d(poly)


def test_polygon_centroid_and_sampling_by_length():
    poly = Polygon.from_vertices([[0, 0], [3, 0], [0, 4]])  # edges 3, 5, 4
    assert np.allclose(poly.center, [1, 4 / 3])
    points, normals = poly.sample_surface(60_000, RNG(1))
    assert_unit(normals)
    on_x, on_y = np.isclose(points[:, 1], 0), np.isclose(points[:, 0], 0)
    assert np.allclose([on_x.mean(), on_y.mean()], [3 / 12, 4 / 12], atol=0.01)
    assert np.isclose(points[on_x, 0].mean(), 1.5, atol=0.03)
    assert np.allclose(normals[on_x], [0, -1]) and np.allclose(normals[on_y], [-1, 0])


def test_polygon_csv(tmp_path):
    rows = "0,0\n2,0\n2,1\n0,1\n"
    (tmp_path / "plain.csv").write_text(rows)
    (tmp_path / "header.csv").write_text("# a rectangle\nx,y\n" + rows.replace(",", ", ") + "\n")
    (tmp_path / "hole.csv").write_text("x;y\n0.5;0.25\n0.5;0.75\n1;0.75\n")
    plain = objects.load(tmp_path / "plain.csv")
    header = Polygon.from_csv(tmp_path / "header.csv")
    assert isinstance(plain, Polygon) and plain.name == "plain"
    assert np.array_equal(plain.rings[0], header.rings[0])
    holed = Polygon.from_csv(tmp_path / "plain.csv", holes=[tmp_path / "hole.csv"])
    assert len(holed.rings) == 2 and np.isclose(holed.area, 2 - 0.125)
    assert_outward_2d(holed)


@pytest.mark.parametrize("text, message", [
    ("", "no x,y rows"),
    ("x,y\n0,0\nfoo,1\n2,2\n", "line 3"),
    ("0,0,0\n1,0,0\n0,1,0\n", "3 values"),
    ("0,0\n1,1\n", "2 distinct vertices"),
    ("0,0\n1,1\n2,2\n", "zero area"),
    ("0,0\n1,1\n1,0\n0,1\n", "crosses itself"),
    ("0,0\n2,2\n2,0\n0,1\n", "edges 0 and 2 cross"),
])
def test_polygon_csv_errors(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ObjectError, match=message) as info:
        Polygon.from_csv(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_polygon_errors(tmp_path):
    square = [[0, 0], [1, 0], [1, 1], [0, 1]]
    with pytest.raises(ObjectError, match="not inside the exterior"):
        Polygon.from_vertices(square, [[[2, 2], [3, 2], [3, 3]]])
    with pytest.raises(ObjectError, match="shape"):
        Polygon.from_vertices([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    with pytest.raises(ObjectError, match="non-finite"):
        Polygon.from_vertices([[0, 0], [1, np.nan], [0, 1]])
    with pytest.raises(ObjectError, match="file not found"):
        Polygon.from_csv(tmp_path / "nope.csv")


# ------------------------------------------------------------------------------------- meshes


def test_mesh_fixes_inverted_and_inconsistent_winding():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    inverted = Mesh.from_trimesh(trimesh.Trimesh(sphere.vertices, sphere.faces[:, ::-1]))
    assert inverted.mesh.volume > 0 and inverted.warnings == ()
    faces = sphere.faces.copy()
    flip = RNG(0).random(len(faces)) < 0.3
    faces[flip] = faces[flip][:, ::-1]
    fixed = Mesh.from_trimesh(trimesh.Trimesh(sphere.vertices, faces))
    assert fixed.mesh.is_volume and "winding was inconsistent" in fixed.warnings[0]
    assert_outward_3d(fixed)


def test_open_mesh_is_oriented_outward_with_a_warning():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    upper = sphere.faces[sphere.triangles_center[:, 2] > 0.2][:, ::-1]
    obj = Mesh.from_trimesh(trimesh.Trimesh(sphere.vertices, upper))
    assert any("open" in w for w in obj.warnings)
    centroids, normals = obj.facets()
    assert np.all(np.einsum("ij,ij->i", centroids, normals) > 0)
    area_centroid = (obj.mesh.area_faces[:, None] * centroids).sum(0) / obj.mesh.area
    assert np.allclose(obj.center, area_centroid)


def test_mesh_bodies_and_degenerate_faces():
    a = trimesh.creation.box()
    b = trimesh.creation.box()
    b.apply_translation([3, 0, 0])
    two = trimesh.util.concatenate([a, b])
    vertices = np.vstack([two.vertices, [[0, 0, 0], [1, 1, 1]]])
    faces = np.vstack([two.faces, [[0, len(vertices) - 2, 0], [1, 2, 1]]])  # zero-area triangles
    obj = Mesh.from_trimesh(trimesh.Trimesh(vertices, faces, process=False), name="two")
    assert len(obj.mesh.faces) == 24 and np.allclose(obj.center, [1.5, 0, 0])
    assert any("2 separate bodies" in w for w in obj.warnings)
    assert any("zero-area" in w for w in obj.warnings)


def test_mesh_uv_seams_are_merged(tmp_path):
    box = trimesh.creation.box()
    lines = []
    for k, face in enumerate(box.faces):  # every triangle gets its own vertices and uv
        lines += [f"v {x} {y} {z}" for x, y, z in box.vertices[face]]
        lines += [f"vt {u} {v}" for u, v in RNG(k).random((3, 2))]
        lines.append(f"f {3 * k + 1}/{3 * k + 1} {3 * k + 2}/{3 * k + 2} {3 * k + 3}/{3 * k + 3}")
    (tmp_path / "seams.obj").write_text("\n".join(lines) + "\n")
    obj = objects.load(tmp_path / "seams.obj")
    assert obj.mesh.is_watertight and obj.warnings == () and len(obj.mesh.vertices) == 8
    assert obj.source == str((tmp_path / "seams.obj").resolve())  # results name the file they came from


def test_mesh_errors(tmp_path):
    (tmp_path / "empty.obj").write_text("")
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\n")
    (tmp_path / "shape.xyz1").write_text("not a mesh\n")
    soup = trimesh.Trimesh(RNG(0).random((30, 3)), np.arange(30).reshape(10, 3), process=False)
    soup.export(tmp_path / "soup.stl")
    for name, message in [("empty.obj", "no triangles"), ("points.obj", "no triangles"),
                          ("shape.xyz1", "cannot read"), ("soup.stl", "triangle soup"),
                          ("missing.stl", "file not found")]:
        with pytest.raises(ObjectError, match=message) as info:
            Mesh.from_file(tmp_path / name)
        assert name in str(info.value) and "\n" not in str(info.value)
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(ObjectError, match="zero area"):
        Mesh.from_trimesh(flat)


# ------------------------------------------------------------------------------------- shapes


SHAPES = [Sphere(1.5), Ellipsoid((3.0, 2.0, 1.0)), Box((2.0, 1.0, 0.5)), Cylinder(0.5, 2.0)]


def exact_normals(shape, points):
    """Surface residual and exact outward normal, written out per shape."""
    if isinstance(shape, Sphere):
        return np.linalg.norm(points, axis=1) - shape.radius, points / shape.radius
    if isinstance(shape, Ellipsoid):
        g = points / shape.axes**2
        return (points**2 / shape.axes**2).sum(1) - 1, g / np.linalg.norm(g, axis=1, keepdims=True)
    if isinstance(shape, Box):
        q = np.abs(points) / (shape.extents / 2)
        axis = np.argmax(q, 1)
        n = np.zeros_like(points)
        n[np.arange(len(points)), axis] = np.sign(points[np.arange(len(points)), axis])
        return q.max(1) - 1, n
    r, half = shape.section_radius, shape.height / 2
    rho = np.linalg.norm(points[:, :2], axis=1)
    cap = np.isclose(np.abs(points[:, 2]), half) & (rho < r * (1 - 1e-9))
    side = np.column_stack([points[:, :2] / r, 0 * rho])
    n = np.where(cap[:, None], [0, 0, 1] * np.sign(points[:, 2:]), side)
    return np.maximum(rho / r, np.abs(points[:, 2]) / half) - 1, n


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: type(s).__name__)
def test_shapes_exact_normals(shape):
    for points, normals in [shape.sample_surface(500, RNG(0)), shape.facets()]:
        residual, expected = exact_normals(shape, points)
        assert np.allclose(residual, 0, atol=1e-12)
        assert np.allclose(normals, expected, atol=1e-12)
    assert shape.mesh.is_watertight and shape.mesh.is_volume
    assert np.isclose(shape.radius, np.linalg.norm(shape.mesh.vertices, axis=1).max())


def test_shape_errors():
    for make in [lambda: Sphere(0), lambda: Box((1, -1, 1)), lambda: Cylinder(1, np.inf),
                 lambda: Ellipsoid((1, 2, 0))]:
        with pytest.raises(ObjectError, match="> 0"):
            make()


def test_area_uniform_sampling():
    ellipsoid = Ellipsoid((3.0, 2.0, 1.0))
    points, _ = ellipsoid.sample_surface(100_000, RNG(2))
    fine = trimesh.creation.icosphere(subdivisions=4)
    fine = trimesh.Trimesh(fine.vertices * ellipsoid.axes, fine.faces)
    centers, area = fine.triangles_center, fine.area_faces
    for coord, cut in [(2, 0.5), (0, 1.5)]:  # uniform on the sphere would give 0.25 and 0.50
        expected = area[np.abs(centers[:, coord]) > cut].sum() / area.sum()
        assert abs((np.abs(points[:, coord]) > cut).mean() - expected) < 0.01
    box = Box((1.0, 2.0, 4.0))
    _, normals = box.sample_surface(60_000, RNG(3))
    shares = np.abs(normals).mean(0)  # fraction of points on the faces normal to x, y, z
    assert np.allclose(shares, np.array([8, 4, 2]) / 14, atol=0.01)
    cylinder = Cylinder(1.0, 1.0)
    _, normals = cylinder.sample_surface(60_000, RNG(4))
    assert abs((np.abs(normals[:, 2]) > 0.5).mean() - 1 / 2) < 0.01  # caps 2 pi, side 2 pi


def test_mesh_sampling_is_area_uniform():
    tetra = trimesh.Trimesh([[0, 0, 0], [4, 0, 0], [0, 2, 0], [0, 0, 1]],
                            [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    obj = Mesh.from_trimesh(tetra)
    assert obj.warnings == ()
    points, normals = obj.sample_surface(100_000, RNG(5))
    assert_unit(normals)
    centroids, face_normals = obj.facets()
    face = np.argmax(normals @ face_normals.T, axis=1)
    share = np.bincount(face, minlength=4) / len(face)
    assert np.allclose(share, obj.mesh.area_faces / obj.mesh.area, atol=0.01)
    for k in range(4):
        assert np.allclose(points[face == k].mean(0), centroids[k], atol=0.03)
    assert np.allclose(np.einsum("ij,ij->i", points - centroids[face], normals), 0, atol=1e-12)


# -------------------------------------------------------------------------------- shared data


def _shared_files(kind: str) -> list[Path]:
    folder = Path(__file__).resolve().parents[2] / "shared" / "data" / kind
    return sorted(p for p in folder.glob("*.*") if p.is_file()) if folder.is_dir() else []


@pytest.mark.parametrize("path", _shared_files("meshes") + _shared_files("polygons"), ids=lambda p: p.name)
def test_shared_file_loads_or_says_why(shared_data, path):
    try:
        obj = objects.load(path)
    except ObjectError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc)
        assert path.name == "trimesh_soup.stl"  # the only file we expect to refuse
        return
    assert obj.dim == (2 if path.suffix == ".csv" else 3)
    assert np.isfinite(obj.center).all() and obj.radius > 0
    centroids, normals = obj.facets()
    assert_unit(normals)
    points, normals = obj.sample_surface(100, RNG(0))
    assert np.isfinite(points).all()
    assert_unit(normals)
    assert all(isinstance(w, str) and "\n" not in w for w in obj.warnings)
    if obj.dim == 2:
        assert_outward_2d(obj)


@pytest.mark.parametrize("name, clean", [
    ("pyvista_nut.ply", True), ("trimesh_featuretype.STL", True), ("ycb_065-a_cups.obj", True),
    ("trimesh_bunny_stanford_res2.ply", False), ("pybullet_mug.obj", False),
    ("pybullet_random_urdf_000.obj", False),
])
def test_shared_mesh_warnings_and_normals(shared_data, name, clean):
    path = shared_data / "meshes" / name
    if not path.is_file():
        pytest.skip(f"{path} not found")
    obj = objects.load(path)
    assert (obj.warnings == ()) == clean
    if clean:
        assert obj.mesh.is_volume
        assert_outward_3d(obj, count=12)


def test_shared_wrench_with_hole(shared_data):
    folder = shared_data / "polygons"
    exterior, hole = folder / "trimesh_wrench_exterior.csv", folder / "trimesh_wrench_hole.csv"
    wrench = Polygon.from_csv(exterior, holes=[hole])
    solid = Polygon.from_csv(exterior)
    assert len(wrench.rings) == 2 and wrench.area < solid.area
    assert_outward_2d(wrench)
