"""The scene data model: triangle meshes with materials and ground truth.

A :class:`Scene` is what the simulator scans. It is plain data: every object
is a triangle mesh in world coordinates (metres) with one :class:`Material`
and a JSON-ready ``truth`` dictionary. The index of an object in
``Scene.objects`` is its stable id; the ``truth_id`` arrays of simulated scans
refer to it (``-1`` means "no object").

Composite things (a tree, an orchard row) are expanded into many objects, one
per leaf and one per woody part, so that every leaf can be scored on its own.
Objects that come from the same scene-file entry share a ``group`` name.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from scenes.errors import SceneError
from scenes.primitives import cross


@dataclass(frozen=True)
class Material:
    """Optical properties of a surface at the scanner wavelength (785 nm).

    Parameters
    ----------
    name : str
        Library name (e.g. ``"spectralon-99"``) or a free label.
    reflectance : float
        Lambertian (hemispherical) reflectance in [0, 1].
    transmittance : float, optional
        Diffuse transmittance in [0, 1], used only by the optional
        leaf-transmission model of the simulator. ``reflectance +
        transmittance`` must not exceed 1.
    """

    name: str
    reflectance: float
    transmittance: float = 0.0

    def __post_init__(self):
        for key in ("reflectance", "transmittance"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and 0.0 <= value <= 1.0):
                raise SceneError(f"material {self.name!r}: {key} must be a number in [0, 1], got {value!r}")
        if self.reflectance + self.transmittance > 1.0 + 1e-12:
            raise SceneError(
                f"material {self.name!r}: reflectance + transmittance must not exceed 1 "
                f"(got {self.reflectance} + {self.transmittance})"
            )


@dataclass
class SceneObject:
    """One scannable object: a triangle mesh with a material and its truth.

    Parameters
    ----------
    name : str
        Unique name within the scene.
    type : str
        Object type (``"plane"``, ``"leaf"``, ``"branch"``, ...).
    vertices : ndarray, shape (V, 3)
        Vertex positions in world coordinates, metres.
    faces : ndarray, shape (F, 3)
        Vertex indices of each triangle.
    material : Material
        Surface material.
    truth : dict, optional
        JSON-ready ground truth of the object (e.g. ``area_m2``, ``normal``,
        ``elevation_deg``, ``azimuth_deg`` for leaves, ``cylinders`` for
        branches).
    group : str, optional
        Name of the scene-file entry the object was expanded from (defaults to
        ``name``).
    face_labels : ndarray, shape (F,), optional
        Integer label of every triangle (e.g. blade / petiole of a leaf); the
        label names are listed in ``truth["labels"]``.
    """

    name: str
    type: str
    vertices: np.ndarray
    faces: np.ndarray
    material: Material
    truth: dict = field(default_factory=dict)
    group: str = ""
    face_labels: np.ndarray | None = None

    def __post_init__(self):
        self.vertices = np.asarray(self.vertices, dtype=np.float64)
        self.faces = np.asarray(self.faces, dtype=np.int64)
        if not self.group:
            self.group = self.name
        where = f"object {self.name!r} ({self.type})"
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise SceneError(f"{where}: vertices must have shape (V, 3), got {self.vertices.shape}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3 or len(self.faces) == 0:
            raise SceneError(f"{where}: faces must have shape (F, 3) with F >= 1, got {self.faces.shape}")
        if not np.all(np.isfinite(self.vertices)):
            raise SceneError(f"{where}: vertices contain NaN or infinite coordinates")
        if self.faces.min() < 0 or self.faces.max() >= len(self.vertices):
            raise SceneError(f"{where}: face indices must lie in [0, {len(self.vertices) - 1}]")
        if self.face_labels is not None:
            self.face_labels = np.asarray(self.face_labels, dtype=np.int32)
            if self.face_labels.shape != (len(self.faces),):
                raise SceneError(f"{where}: face_labels must have one entry per face ({len(self.faces)}), "
                                 f"got shape {self.face_labels.shape}")
        if not np.any(self.face_areas() > 0):
            raise SceneError(f"{where}: the mesh is degenerate (all triangles have zero area)")

    def face_areas(self) -> np.ndarray:
        """Area of every triangle, m²."""
        return 0.5 * np.linalg.norm(self._face_cross(), axis=1)

    def face_normals(self) -> np.ndarray:
        """Unit geometric normal of every triangle (zero for degenerate ones)."""
        cross = self._face_cross()
        norm = np.linalg.norm(cross, axis=1, keepdims=True)
        return np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)

    def _face_cross(self) -> np.ndarray:
        v = self.vertices[self.faces]
        return cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])


@dataclass
class Scene:
    """A set of objects to scan, plus the scanner set-up the scene suggests.

    Parameters
    ----------
    objects : list of SceneObject
        The objects; the list index is the object id.
    scanner : dict, optional
        The scene file's ``scanner`` section as plain data (``preset``,
        ``position``, ``window``, ``step_deg`` and scanner-model overrides).
        The simulator interprets it; the scene package does not.
    name : str, optional
        Scene name.
    spec : dict, optional
        The description the scene was built from (see
        :mod:`scenes.scenefile`); ``None`` for scenes assembled from meshes.
    """

    objects: list[SceneObject]
    scanner: dict = field(default_factory=dict)
    name: str = ""
    spec: dict | None = None

    def __post_init__(self):
        duplicated = sorted(n for n, k in Counter(o.name for o in self.objects).items() if k > 1)
        if duplicated:
            raise SceneError(f"scene {self.name!r}: object names must be unique, repeated: {duplicated}")

    @property
    def object_names(self) -> list[str]:
        """Object names, indexed by object id."""
        return [o.name for o in self.objects]

    def truth(self) -> list[dict]:
        """Ground truth of every object as JSON-ready dictionaries.

        Returns
        -------
        list of dict
            One entry per object with ``id``, ``name``, ``type``, ``group``,
            ``material`` and the object's own truth fields.
        """
        return [
            {"id": i, "name": o.name, "type": o.type, "group": o.group, "material": o.material.name, **o.truth}
            for i, o in enumerate(self.objects)
        ]

    def merged_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All objects as one triangle soup.

        Returns
        -------
        vertices : ndarray, shape (V, 3), float64
            World coordinates, metres.
        faces : ndarray, shape (F, 3), int64
            Triangles indexing ``vertices``.
        face_object : ndarray, shape (F,), int32
            Object id of every triangle.
        """
        if not self.objects:
            raise SceneError(f"scene {self.name!r} has no objects: there is nothing to scan")
        offsets = np.cumsum([0] + [len(o.vertices) for o in self.objects])
        vertices = np.concatenate([o.vertices for o in self.objects])
        faces = np.concatenate([o.faces + off for o, off in zip(self.objects, offsets)])
        face_object = np.concatenate(
            [np.full(len(o.faces), i, dtype=np.int32) for i, o in enumerate(self.objects)]
        )
        return vertices, faces, face_object

    def with_scanner(self, **changes) -> "Scene":
        """A copy of the scene whose scanner section is updated with ``changes``."""
        scanner = {**self.scanner, **changes}
        spec = None if self.spec is None else {**self.spec, "scanner": scanner}
        return dataclasses.replace(self, scanner=scanner, spec=spec)
