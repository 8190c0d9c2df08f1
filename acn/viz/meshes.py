"""The A1's visual meshes, read from the same URDF the simulators are built from.

``link_meshes()`` parses the ``<visual>`` elements of ``pybullet_data/a1/a1.urdf`` and loads
their ``.obj`` files into triangle meshes expressed in each LINK frame (the visual origin's
rotation, translation and scale are applied to the vertices), so a mesh is drawn by giving it
the link's world pose and nothing else.

The original meshes have about 38k vertices per robot; the view logs one copy per robot and
episode, so they are simplified by vertex clustering on a ``cell`` grid (default 7 mm, about 8k
vertices per robot). The result is cached per process.
"""

from __future__ import annotations

import functools
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from acn.sim.robot import urdf_path
from acn.sim.rotations import quat_to_matrix, rpy_to_quat

DEFAULT_CELL = 0.007  # m, vertex-clustering grid of the simplified meshes


@dataclass(frozen=True)
class LinkMesh:
    """A triangle mesh in the frame of URDF link ``link`` (m)."""

    link: str
    vertices: np.ndarray   # (V, 3) float32, link frame, m
    triangles: np.ndarray  # (F, 3) uint32, counter-clockwise seen from outside
    normals: np.ndarray    # (V, 3) float32, unit vertex normals, link frame


def load_obj(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (F, 3, zero-based) of a Wavefront .obj (polygons fanned)."""
    vertices, faces = [], []
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if line.startswith("v "):
                vertices.append(line.split()[1:4])
            elif line.startswith("f "):
                idx = [int(t.split("/")[0]) for t in line.split()[1:]]
                faces.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1))
    v = np.asarray(vertices, dtype=np.float64)
    tri = np.asarray(faces, dtype=np.int64)
    tri = np.where(tri < 0, tri + len(v), tri - 1)  # .obj indices are 1-based, negative = from the end
    return v, tri


def simplify(vertices: np.ndarray, triangles: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering: merge vertices within one ``cell`` (m) grid cube, drop degenerate triangles."""
    key = np.floor(vertices / cell).astype(np.int64)
    _, cluster = np.unique(key, axis=0, return_inverse=True)
    cluster = cluster.ravel()
    counts = np.bincount(cluster)
    merged = np.zeros((len(counts), 3))
    np.add.at(merged, cluster, vertices)
    merged /= counts[:, None]
    tri = cluster[triangles]
    tri = tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])]
    _, first = np.unique(np.sort(tri, axis=1), axis=0, return_index=True)
    return merged, tri[np.sort(first)]


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    face = np.cross(b - a, c - a)
    n = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(n, triangles[:, k], face)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)


def _floats(text: str | None, default: tuple[float, ...]) -> np.ndarray:
    return np.array([float(x) for x in text.split()]) if text else np.array(default, dtype=float)


@functools.lru_cache(maxsize=4)
def link_meshes(cell: float = DEFAULT_CELL) -> tuple[LinkMesh, ...]:
    """Every URDF link with a mesh visual, simplified on a ``cell`` grid (0: original meshes)."""
    path = urdf_path()
    root = ET.parse(path).getroot()
    out = []
    for link in root.iter("link"):
        for visual in link.findall("visual"):
            mesh = visual.find("geometry/mesh")
            if mesh is None:
                continue  # the URDF's only other visual is a 1 mm box on the IMU link
            origin = visual.find("origin")
            xyz = _floats(origin.get("xyz") if origin is not None else None, (0, 0, 0))
            rpy = _floats(origin.get("rpy") if origin is not None else None, (0, 0, 0))
            scale = _floats(mesh.get("scale"), (1, 1, 1))
            v, tri = load_obj(os.path.join(os.path.dirname(path), mesh.get("filename")))
            if cell > 0:
                v, tri = simplify(v, tri, cell)
            v = (v * scale) @ quat_to_matrix(rpy_to_quat(rpy)).T + xyz  # URDF rpy: extrinsic XYZ
            if np.linalg.det(np.diag(scale)) < 0:
                tri = tri[:, ::-1]  # a mirroring scale flips the winding
            out.append(LinkMesh(link.get("name"), v.astype(np.float32), tri.astype(np.uint32),
                                vertex_normals(v, tri).astype(np.float32)))
    return tuple(out)
