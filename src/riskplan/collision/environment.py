"""Obstacle environments: closed triangle meshes (3-D) or simple polygons (2-D).

An :class:`Environment` is a set of solid obstacles, each bounded by closed, consistently
oriented faces (triangles in 3-D, polygon edges in 2-D). Obstacles may overlap; an obstacle
may have several shells (a hollow body wall is an outer shell plus an inverted inner shell).
"Inside the environment" means inside at least one obstacle (winding number >= 1).

Closest-point queries in 3-D use libigl's AABB tree (measured against coal/python-fcl and
trimesh in ``riskplan.bench.collision``: libigl answers a batch in one call with no Python
loop, so it is the fastest here for the batch sizes we use). The collision estimators do not
need world-space closest points: they work on whitened faces directly (``_kernels``).
"""

from __future__ import annotations

import logging
import math
from functools import cached_property
from pathlib import Path

import numpy as np

from riskplan.collision import _kernels as K
from riskplan.collision.geometry import (
    as_point,
    as_points,
    check_closed_mesh,
    check_closed_polyline,
    check_finite_vertices,
    extrude_polygon,
    polygon_order,
    signed_volume,
    whiten,
)
from riskplan.errors import InvalidInputError
from riskplan.geometry2d import (
    check_simple_polygon,
    closest_points_on_segments,
    contains_points,
    edge_segments,
    polygon_area,
    polygon_edges,
    segments_hit,
    winding_numbers,
)

log = logging.getLogger(__name__)


class Environment:
    """Solid obstacles in ``d = 2`` or ``3`` dimensions.

    Attributes
    ----------
    vertices : (V, d) float64
    faces : (F, d) int64
        Triangles (3-D) or directed polygon edges (2-D); outward-oriented.
    face_obstacle : (F,) int64
        Obstacle index of each face.
    names : tuple[str, ...]
        One name per obstacle.

    Build with :meth:`from_meshes`, :meth:`from_polygons`, :meth:`from_arrays` or :meth:`load`.
    """

    def __init__(self, vertices, faces, face_obstacle=None, names=None, *, validate: bool = True):
        V = np.ascontiguousarray(vertices, dtype=np.float64)
        F = np.ascontiguousarray(faces, dtype=np.int64)
        if V.ndim != 2 or V.shape[1] not in (2, 3):
            raise InvalidInputError(f"vertices: expected shape (V, 2) or (V, 3), got {V.shape}")
        d = V.shape[1]
        if F.ndim != 2 or F.shape[1] != d:
            raise InvalidInputError(
                f"faces: expected shape (F, {d}) ({'triangles' if d == 3 else 'segments'} for d={d}), got {F.shape}"
            )
        if F.shape[0] == 0:
            raise InvalidInputError("environment is empty: no obstacle faces")
        fo = (
            np.zeros(len(F), dtype=np.int64)
            if face_obstacle is None
            else np.ascontiguousarray(face_obstacle, dtype=np.int64)
        )
        if fo.shape != (len(F),):
            raise InvalidInputError(f"face_obstacle: expected shape ({len(F)},), got {fo.shape}")
        n_obs = int(fo.max()) + 1
        if names is None:
            names = tuple(f"obstacle{i}" for i in range(n_obs))
        names = tuple(str(n) for n in names)
        if len(names) != n_obs:
            raise InvalidInputError(
                f"names: expected {n_obs} names (one per obstacle), got {len(names)}"
            )
        if validate:
            if not np.all(np.isfinite(V)):
                raise InvalidInputError("vertices: contain NaN or inf")
            if fo.min() < 0:
                raise InvalidInputError("face_obstacle: negative obstacle index")
            for i in range(n_obs):
                sel = F[fo == i]
                if d == 3:
                    check_closed_mesh(V, sel, f"obstacle {names[i]!r}")
                else:
                    check_closed_polyline(V, sel, f"obstacle {names[i]!r}")
        self.vertices = V
        self.faces = F
        self.face_obstacle = fo
        self.names = names

    # ------------------------------------------------------------ constructors
    @classmethod
    def from_meshes(cls, meshes, names=None, *, fix_orientation: bool = True) -> Environment:
        """One obstacle per closed triangle mesh.

        Each mesh must be closed (watertight), edge-manifold, consistently oriented and free of
        degenerate triangles, else :class:`InvalidInputError`.

        Parameters
        ----------
        meshes : sequence of trimesh.Trimesh or (vertices (V, 3), faces (F, 3)) pairs
        names : sequence of str, optional
            One per mesh (default ``obstacle0``, ``obstacle1``, ...).
        fix_orientation : bool
            Flip a mesh with negative enclosed volume (inward normals) instead of raising.

        Returns
        -------
        Environment
        """
        meshes = list(meshes)
        if not meshes:
            raise InvalidInputError("meshes: environment is empty (no obstacles given)")
        if names is not None and len(names) != len(meshes):
            raise InvalidInputError(f"names: expected {len(meshes)} names, got {len(names)}")
        names = list(names) if names is not None else [f"obstacle{i}" for i in range(len(meshes))]
        Vs, Fs, owners = [], [], []
        offset = 0
        for i, m in enumerate(meshes):
            if hasattr(m, "vertices") and hasattr(m, "faces"):
                V, F = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)
            else:
                try:
                    V, F = m
                except (TypeError, ValueError) as exc:
                    raise InvalidInputError(
                        f"meshes[{i}]: expected a Trimesh or a (vertices, faces) pair"
                    ) from exc
                V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
            if V.ndim != 2 or V.shape[1] != 3:
                raise InvalidInputError(
                    f"meshes[{i}] ({names[i]!r}): vertices must have shape (V, 3), got {V.shape}"
                )
            check_finite_vertices(V, f"meshes[{i}] ({names[i]!r})")
            if F.ndim != 2 or F.shape[1] != 3:
                raise InvalidInputError(
                    f"meshes[{i}] ({names[i]!r}): faces must have shape (F, 3) triangles, got {F.shape}"
                )
            if not np.all(np.isfinite(V)):
                raise InvalidInputError(f"meshes[{i}] ({names[i]!r}): vertices contain NaN or inf")
            check_closed_mesh(V, F, f"mesh {names[i]!r}")
            if signed_volume(V, F) < 0:
                if not fix_orientation:
                    raise InvalidInputError(
                        f"mesh {names[i]!r}: faces point inwards (negative enclosed volume)"
                    )
                log.info("mesh %r had inward normals; flipped", names[i])
                F = F[:, ::-1]
            Vs.append(V)
            Fs.append(F + offset)
            owners.append(np.full(len(F), i, dtype=np.int64))
            offset += len(V)
        return cls(np.vstack(Vs), np.vstack(Fs), np.concatenate(owners), names, validate=False)

    @classmethod
    def from_polygons(cls, polygons, names=None, *, validate: bool = True) -> Environment:
        """2-D environment: one solid obstacle per simple polygon (re-oriented counter-clockwise).

        Self-intersecting, degenerate or zero-area polygons raise :class:`InvalidInputError`.

        Parameters
        ----------
        polygons : sequence of array_like, each (k, 2)
        names : sequence of str, optional
        validate : bool
            ``False`` skips the (quadratic) self-intersection and finiteness checks for polygons
            known to be simple, e.g. the deformed obstacles of a tissue state, rebuilt at every
            plan step.

        Returns
        -------
        Environment
        """
        polygons = list(polygons)
        if not polygons:
            raise InvalidInputError("polygons: environment is empty (no obstacles given)")
        if names is not None and len(names) != len(polygons):
            raise InvalidInputError(f"names: expected {len(polygons)} names, got {len(names)}")
        Vs, Fs, owners = [], [], []
        offset = 0
        for i, p in enumerate(polygons):
            arr = np.asarray(p, dtype=np.float64)
            if arr.ndim != 2 or arr.shape[1] != 2:
                raise InvalidInputError(f"polygons[{i}]: expected shape (k, 2), got {arr.shape}")
            if validate:
                if not np.all(np.isfinite(arr)):
                    raise InvalidInputError(f"polygons[{i}]: contains NaN or inf")
                arr = check_simple_polygon(arr, f"polygons[{i}]")
            elif polygon_area(arr) < 0:
                arr = arr[::-1]
            k = len(arr)
            Vs.append(arr)
            Fs.append(polygon_edges(k, offset))
            owners.append(np.full(k, i, dtype=np.int64))
            offset += k
        return cls(np.vstack(Vs), np.vstack(Fs), np.concatenate(owners), names, validate=False)

    @classmethod
    def from_arrays(cls, vertices, faces, face_obstacle=None, names=None) -> Environment:
        """From raw arrays; every obstacle is checked to be closed.

        Parameters
        ----------
        vertices : array_like, (V, d)
        faces : array_like of int, (F, d)
            Triangles for d = 3, directed edges for d = 2; outward-oriented.
        face_obstacle : array_like of int, (F,), optional
            Obstacle of each face (default: all one obstacle).
        names : sequence of str, optional

        Returns
        -------
        Environment
        """
        return cls(vertices, faces, face_obstacle, names, validate=True)

    @classmethod
    def load(cls, paths, *, split: bool = False, names=None) -> Environment:
        """Load STL/OBJ/PLY/OFF file(s) with trimesh; one obstacle per file.

        Parameters
        ----------
        paths : str or path or sequence of them
        split : bool
            Make each connected component its own obstacle (do not use it for hollow bodies whose
            inner shell is a separate component).
        names : sequence of str, optional
            Default: the file stems (``stem_j`` for split components).

        Returns
        -------
        Environment
        """
        import trimesh

        from riskplan.io import read_file_with

        if isinstance(paths, (str, Path)):
            paths = [paths]
        meshes, mesh_names = [], []
        for p in paths:
            p = Path(p)
            # unprocessed first: processing drops faces with non-finite vertices, which would
            # then read as a hole ("not closed") instead of naming the vertex
            m = read_file_with(
                p, lambda q: trimesh.load(q, force="mesh", process=False), "mesh file"
            )
            if hasattr(m, "vertices"):
                check_finite_vertices(np.asarray(m.vertices, dtype=np.float64), str(p))
                m.process()
            if len(m.faces) == 0:
                raise InvalidInputError(f"{p}: mesh has no faces")
            parts = m.split(only_watertight=False) if split else [m]
            for j, part in enumerate(parts):
                meshes.append(part)
                mesh_names.append(p.stem if len(parts) == 1 else f"{p.stem}_{j}")
        return cls.from_meshes(meshes, names=names or mesh_names)

    # ------------------------------------------------------------- properties
    @property
    def dim(self) -> int:
        return self.vertices.shape[1]

    @property
    def n_faces(self) -> int:
        return self.faces.shape[0]

    @property
    def n_obstacles(self) -> int:
        return len(self.names)

    @property
    def bounds(self) -> np.ndarray:
        """``(2, d)``: lower and upper corner of the vertices."""
        return np.stack([self.vertices.min(0), self.vertices.max(0)])

    def __repr__(self) -> str:
        kind = "triangles" if self.dim == 3 else "edges"
        return f"Environment(d={self.dim}, obstacles={self.n_obstacles}, {kind}={self.n_faces})"

    def obstacle(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """One obstacle's own mesh (3-D) or polygon (2-D).

        Parameters
        ----------
        i : int
            The obstacle's index.

        Returns
        -------
        vertices : numpy.ndarray, shape (n, d)
            Its vertices (m).
        faces : numpy.ndarray, shape (F, d)
            Its faces (triangles, or directed edges in 2-D), indices into ``vertices``.
        """
        F = self.faces[self.face_obstacle == i]
        used, inv = np.unique(F, return_inverse=True)
        return self.vertices[used], inv.reshape(F.shape)

    def subset(self, obstacles) -> Environment:
        """A new environment with only the named (or indexed) obstacles.

        Parameters
        ----------
        obstacles : iterable of str or int
            Obstacle names or indices, in the new environment's order.

        Returns
        -------
        Environment
        """
        idx = [self.names.index(o) if isinstance(o, str) else int(o) for o in obstacles]
        parts = [self.obstacle(i) for i in idx]
        if self.dim == 3:
            return Environment.from_meshes(
                parts, names=[self.names[i] for i in idx], fix_orientation=False
            )
        Vs, Fs, owners, off = [], [], [], 0
        for j, (V, F) in enumerate(parts):
            Vs.append(V)
            Fs.append(F + off)
            owners.append(np.full(len(F), j))
            off += len(V)
        return Environment(
            np.vstack(Vs),
            np.vstack(Fs),
            np.concatenate(owners),
            [self.names[i] for i in idx],
            validate=False,
        )

    def to_trimesh(self):
        """All obstacles as one mesh (3-D only).

        Returns
        -------
        trimesh.Trimesh
        """
        import trimesh

        if self.dim != 3:
            raise InvalidInputError(
                "to_trimesh: only 3-D environments are meshes; use extrude() first"
            )
        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    def save(self, path) -> Path:
        """Write all obstacles to one mesh file, atomically (3-D).

        Parameters
        ----------
        path : str or path
            The file; its suffix names the format (.stl, .obj, .ply; .stl without one).

        Returns
        -------
        pathlib.Path
            ``path``.
        """
        from riskplan.io import atomic_path

        path = Path(path)
        with atomic_path(path) as tmp:
            self.to_trimesh().export(tmp, file_type=path.suffix.lstrip(".").lower() or "stl")
        return path

    def extrude(self, z0: float = -1.0, z1: float = 1.0) -> Environment:
        """The 3-D environment of the prisms ``polygon x [z0, z1]`` (from a 2-D one).

        Parameters
        ----------
        z0, z1 : float
            The prisms' bottom and top (m).

        Returns
        -------
        Environment
            One closed prism per obstacle, with the same names.
        """
        if self.dim != 2:
            raise InvalidInputError("extrude: environment is already 3-D")
        meshes = []
        for i in range(self.n_obstacles):
            V, F = self.obstacle(i)
            order = polygon_order(F)
            meshes.append(extrude_polygon(V[order], z0, z1))
        return Environment.from_meshes(meshes, names=self.names)

    def whitened(self, mean, precision_cholesky) -> Environment:
        """The environment in the whitened frame ``y = U (x - mu)`` of one Gaussian (eq. 8).

        Orientation is preserved (det U > 0).

        Parameters
        ----------
        mean : array_like, (d,)
        precision_cholesky : array_like, (d, d)
            Upper triangular ``U``, ``Sigma^{-1} = U^T U``.

        Returns
        -------
        Environment
        """
        mu = as_point(mean, "mean", self.dim)
        u = np.asarray(precision_cholesky, dtype=np.float64)
        if u.shape != (self.dim, self.dim):
            raise InvalidInputError(
                f"precision_cholesky: expected shape ({self.dim}, {self.dim}), got {u.shape}"
            )
        Vw = whiten(self.vertices, mu, u)
        return Environment(Vw, self.faces, self.face_obstacle, self.names, validate=False)

    # ------------------------------------------------------------- caches
    @cached_property
    def _spheres(self) -> tuple[np.ndarray, np.ndarray]:
        t = self.vertices[self.faces]
        c = t.mean(axis=1)
        r = np.linalg.norm(t - c[:, None, :], axis=2).max(axis=1)
        return np.ascontiguousarray(c), np.ascontiguousarray(r * (1 + 1e-12) + 1e-300)

    @cached_property
    def _segments(self) -> np.ndarray:
        """2-D: ``(E, 4)`` edge rows ``(x0, y0, x1, y1)`` for the planar kernels."""
        return edge_segments(self.vertices, self.faces)

    @cached_property
    def _rotation(self) -> np.ndarray:
        # A fixed generic rotation: rays along its x axis avoid the axis-aligned edges and
        # vertices of typical meshes (a ray through an edge would be counted twice or not at all).
        q, _ = np.linalg.qr(np.random.default_rng(7919).normal(size=(3, 3)))
        return q * np.sign(np.linalg.det(q))

    @cached_property
    def _ray_grid(self):
        Vr = np.ascontiguousarray(self.vertices @ self._rotation.T)
        t = Vr[self.faces][:, :, 1:]
        side = int(min(512, max(1, math.ceil(math.sqrt(self.n_faces / 2)))))
        return (Vr, *_face_grid(t.min(axis=1), t.max(axis=1), side, 2))

    @cached_property
    def _box_grid(self):
        t = self.vertices[self.faces]
        side = int(min(128, max(1, math.ceil((self.n_faces / 2) ** (1 / 3)))))
        return _face_grid(t.min(axis=1), t.max(axis=1), side, 3)

    @cached_property
    def _aabb(self):
        import igl

        tree = igl.AABB()
        tree.init(self.vertices, self.faces)
        return tree

    # ------------------------------------------------------------- queries
    def winding_number(self, points) -> np.ndarray:
        """Integer winding number of points = number of obstacles containing them.

        Points exactly on a 2-D edge follow the half-open crossing rule of
        :func:`riskplan.geometry2d.winding_numbers`; :meth:`contains` counts them as inside.

        Parameters
        ----------
        points : array_like, (..., d)

        Returns
        -------
        numpy.ndarray of int, (...,)
        """
        P, shape = as_points(points, self.dim)
        if self.dim == 3:
            Vr, origin, cell, shape_g, start, items = self._ray_grid
            with np.errstate(
                over="ignore", invalid="ignore"
            ):  # points near the float range are outside anyway
                Pr = np.ascontiguousarray(P @ self._rotation.T)
            w = K.winding_numbers_3d(Vr, self.faces, Pr, origin, cell, shape_g, start, items)
        else:
            w = winding_numbers(self._segments, P)
        return w.reshape(shape)

    def contains(self, points) -> np.ndarray:
        """True where a point lies inside at least one obstacle.

        In 2-D obstacles are closed sets (a point on an edge is inside; the convention of
        :mod:`riskplan.geometry2d`); in 3-D a point exactly on a face may go either way.

        Parameters
        ----------
        points : array_like, (..., d)

        Returns
        -------
        numpy.ndarray of bool, (...,)
        """
        if self.dim == 2:
            P, shape = as_points(points, 2)
            return contains_points(self._segments, P).reshape(shape)
        return self.winding_number(points) > 0

    def closest_points(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest surface points.

        Parameters
        ----------
        points : array_like, (..., d)

        Returns
        -------
        tuple of numpy.ndarray
            ``(distance (...,), closest (..., d), face (...,))``.
        """
        P, shape = as_points(points, self.dim)
        if self.dim == 3 and len(P):
            sq, face, closest = self._aabb.squared_distance(self.vertices, self.faces, P)
            dist = np.sqrt(np.maximum(sq, 0.0))
        else:
            dist, closest, face = closest_points_on_segments(self._segments, P)
        return dist.reshape(shape), closest.reshape(shape + (self.dim,)), face.reshape(shape)

    def signed_distance(self, points) -> np.ndarray:
        """Distance to the nearest surface, negative inside an obstacle.

        Parameters
        ----------
        points : array_like, shape (..., d)
            Query points (m).

        Returns
        -------
        numpy.ndarray, shape (...,)
            Signed distances (m).
        """
        dist, _, _ = self.closest_points(points)
        return np.where(self.contains(points), -dist, dist)

    def segments_collide(self, start, end) -> np.ndarray:
        """True where the segment ``start -> end`` has an endpoint inside or crosses a surface.

        Parameters
        ----------
        start, end : array_like, (..., d)

        Returns
        -------
        numpy.ndarray of bool, (...,)
        """
        P0, shape = as_points(start, self.dim, "start")
        P1, shape1 = as_points(end, self.dim, "end")
        if shape != shape1:
            raise InvalidInputError(f"start and end: shapes differ ({shape} vs {shape1})")
        inside = self.contains(P0) | self.contains(P1)
        if self.dim == 3:
            origin, cell, shape_g, start_g, items = self._box_grid
            cross = K.segments_hit_3d(
                self.vertices, self.faces, P0, P1, origin, cell, shape_g, start_g, items
            )
        else:
            cross = segments_hit(self._segments, P0, P1)
        return (inside | cross).reshape(shape)


def check_environment(environment, name: str = "environment", dim=None) -> Environment:
    """``environment`` if it is an :class:`Environment` (``dim``-dimensional when ``dim`` is
    given), else :class:`InvalidInputError` naming the argument ``name`` and what it got."""
    want = "an Environment" if dim is None else f"a {dim}-D Environment"
    if not isinstance(environment, Environment):
        raise InvalidInputError(f"{name}: expected {want}, got {type(environment).__name__}")
    if dim is not None and environment.dim != dim:
        raise InvalidInputError(f"{name}: expected {want}, got a {environment.dim}-D one")
    return environment


def _face_grid(lo, hi, side: int, dims: int):
    """The uniform grid (``side`` cells a side) over the faces' boxes ``lo, hi (F, dims)``."""
    origin = lo.min(axis=0)
    ext = np.maximum(hi.max(axis=0) - origin, 1e-12)
    shape = np.full(dims, side, dtype=np.int64)
    cell = ext / side * (1 + 1e-9)
    start, items = K.build_grid(
        np.ascontiguousarray(lo), np.ascontiguousarray(hi), origin, cell, shape
    )
    return origin, cell, shape, start, items
