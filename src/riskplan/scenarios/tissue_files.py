"""Tissue shapes of scenario files (:mod:`riskplan.scenarios.files`): the ``[tissue]`` table's
outline from a mesh file (``tissue.mesh``: trimesh for OBJ/STL/PLY/OFF, meshio for the rest,
with the file's named boundary groups) and the needle tissue's fixed boundary
(``fixed_vertices``, ``fixed_edges``, ``fixed_region``, ``fixed_group``).

``r`` below is the reader of :mod:`riskplan.scenarios.files` (typed access to one parsed file;
its errors name the file and the field); this module does not import it, so the two stay free
of an import circle.
"""

from __future__ import annotations

import numpy as np

from riskplan import geometry2d as geo
from riskplan.errors import InvalidInputError

_RECT = {"lo", "hi"}
#: mesh files read through trimesh (the shape only); every other suffix goes to meshio,
#: which also reads named boundary groups (gmsh physical groups, node sets)
_TRIMESH_SUFFIXES = (".obj", ".stl", ".ply", ".off")
#: why a tissue with holes is refused, per scenario (the error says it)
_NO_HOLES = {
    "needle": "the tissue is meshed from one simple outline (riskplan.deformable.mesh_polygon "
    "takes no holes); a region the needle must not enter is an obstacle ([[obstacles]])",
    "manipulation": "the object is meshed from one simple outline, and its boundary is sensed and "
    "checked against the obstacle as one loop (noise.n_boundary points along the outer outline): "
    "a hole's boundary would be neither sensed nor checked",
}


def _boundary_loop(r, f: np.ndarray, kind: str, fname: str) -> list[int]:
    """The vertex loop of the boundary edges (edges of one triangle) of triangles ``f``,
    starting at the vertex the file lists first among them; a second loop (a hole, or a
    second piece) is refused with the reason."""
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = edges[counts[inv.ravel()] == 1]
    nxt = {}
    for a, b in boundary.tolist():
        if a in nxt:
            r.fail("tissue.mesh", f"{fname}: the boundary is not a single simple loop")
        nxt[a] = b
    start = int(boundary[0, 0])
    loop = [start]
    while nxt.get(loop[-1], start) != start:
        loop.append(nxt[loop[-1]])
        if len(loop) > len(boundary):
            r.fail("tissue.mesh", f"{fname}: the boundary is not a single simple loop")
    if len(loop) != len(boundary):
        r.fail(
            "tissue.mesh",
            f"{fname}: the boundary has {len(boundary)} edges but its first loop {len(loop)}: "
            f"holes or several pieces are not supported ({_NO_HOLES[kind]})",
        )
    return loop


def _read_tissue_mesh(r, name, kind: str) -> tuple[np.ndarray, dict]:
    """``(outline (n, 2), groups)`` of a planar triangle mesh file (``tissue.mesh``, relative
    to the scenario file), lengths in *L* like the others.

    OBJ, STL, PLY and OFF are read with trimesh; every other format meshio reads (gmsh
    ``.msh``, VTK ``.vtk``/``.vtu``, XDMF, Abaqus ``.inp``, MEDIT ``.mesh``, ...) with
    meshio, which also gives the file's named groups: ``groups[name]`` is ``(k, 2, 2)``
    material segments, the line cells of a named cell set (a gmsh physical group) or, for a
    named node set, zero-length segments at its nodes. The outline is the loop of the
    boundary edges (edges of one triangle), counter-clockwise, starting at the vertex the file
    lists first among them. The mesh must lie in a plane ``z = const`` and have one boundary
    loop (no holes). The scenario meshes this outline at its own element count (the mesh
    uncertainty case varies it), so the file gives the shape and the named boundary, not the
    elements."""
    from riskplan.errors import require

    if not isinstance(name, str):
        r.fail("tissue.mesh", f"expected a file name, got {name!r}")
    path = (r.path.parent / name).resolve()
    if not path.is_file():
        r.fail("tissue.mesh", f"no such file {str(path)!r}")
    groups: dict[str, np.ndarray] = {}
    if path.suffix.lower() in _TRIMESH_SUFFIXES:
        trimesh = require("trimesh", "mesh")
        try:
            mesh = trimesh.load(str(path), force="mesh", process=False)
        except Exception as exc:  # a reader's own error types differ per format
            r.fail("tissue.mesh", f"cannot read {path.name}: {exc}")
        v = np.asarray(mesh.vertices, dtype=np.float64)
        f = np.asarray(mesh.faces, dtype=np.int64)
    else:
        meshio = require("meshio", "fem")
        try:
            mesh = meshio.read(str(path))
        except Exception as exc:  # meshio raises its own ReadError and plain errors
            r.fail("tissue.mesh", f"cannot read {path.name}: {exc}")
        v = np.asarray(mesh.points, dtype=np.float64)
        tri = [np.asarray(c.data, dtype=np.int64) for c in mesh.cells if c.type == "triangle"]
        f = np.concatenate(tri) if tri else np.zeros((0, 3), dtype=np.int64)
        groups = _meshio_groups(mesh, v[:, :2] * r.length)
    if len(f) == 0:
        r.fail("tissue.mesh", f"{path.name} has no triangles")
    if v.shape[1] == 3:
        z = v[:, 2]
        if float(np.ptp(z)) > 1e-9 * max(float(np.ptp(v[:, :2], axis=0).max()), 1e-300):
            r.fail("tissue.mesh", f"{path.name} is not planar (z varies by {float(np.ptp(z))})")
    loop = _boundary_loop(r, f, kind, path.name)
    outline = v[loop, :2] * r.length
    if geo.polygon_area(outline) < 0:
        outline = outline[::-1].copy()
    return outline, groups


def _meshio_groups(mesh, xy: np.ndarray) -> dict:
    """Named boundary groups of a meshio mesh as ``{name: (k, 2, 2) segments}``: line cells of
    each named cell set (meshio's ``cell_sets``, or gmsh's ``field_data`` with the
    ``gmsh:physical`` tags) and each named node set (zero-length segments)."""
    out: dict[str, list] = {}
    for name, blocks in mesh.cell_sets_dict.items():
        for ctype, idx in blocks.items():
            if ctype == "line":
                lines = np.concatenate([c.data for c in mesh.cells if c.type == "line"])
                out.setdefault(name, []).append(xy[lines[np.asarray(idx)]])
    phys = mesh.cell_data.get("gmsh:physical")
    if phys is not None:
        for name, (tag, dim) in ((n, tuple(v[:2])) for n, v in mesh.field_data.items()):
            if int(dim) != 1 or name in out:
                continue
            for c, tags in zip(mesh.cells, phys):
                if c.type == "line":
                    sel = np.asarray(c.data)[np.asarray(tags) == tag]
                    if len(sel):
                        out.setdefault(name, []).append(xy[sel])
    for name, idx in (mesh.point_sets or {}).items():
        pts = xy[np.asarray(idx, dtype=np.int64)]
        out.setdefault(name, []).append(np.stack([pts, pts], axis=1))
    return {k: np.concatenate(v).reshape(-1, 2, 2) for k, v in out.items()}


def _clip_outline(outline: np.ndarray, box: np.ndarray) -> np.ndarray:
    """End points ``(k, 2)`` of the pieces of the closed ``outline``'s edges inside the
    axis-aligned ``box [lo, hi]`` (Liang-Barsky clipping of each edge)."""
    out = []
    a, b = outline, np.roll(outline, -1, axis=0)
    for p, q in zip(a, b):
        d = q - p
        t0, t1 = 0.0, 1.0
        for k in range(2):
            for side, bound in ((-1.0, box[0, k]), (1.0, box[1, k])):
                num = side * (bound - p[k])  # distance to the bound along its outward side
                den = side * d[k]
                if den == 0.0:
                    if num < 0.0:
                        t0, t1 = 1.0, 0.0  # parallel and outside
                elif den > 0.0:
                    t1 = min(t1, num / den)
                else:
                    t0 = max(t0, num / den)
        if t0 <= t1:
            out += [p + t0 * d, p + t1 * d]
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def _needle_tissue(r, t: dict) -> dict:
    """The needle's tissue fields of :class:`NeedleConfig`: the rectangle (``width``,
    ``height``) or an ``outline``/``mesh``, and the fixed boundary (``fixed_vertices``,
    ``fixed_edges``, ``fixed_region``, ``fixed_group``; their union; none: the outline's
    vertices, the paper's four corners)."""
    if "holes" in t:
        r.fail("tissue.holes", f"a tissue with holes is not supported: {_NO_HOLES['needle']}")
    shape_keys = [k for k in ("outline", "mesh") if k in t]
    rect = [k for k in ("width", "height") if k in t]
    if len(shape_keys) > 1 or (shape_keys and rect):
        r.fail("tissue", "expected one of width/height, outline, mesh")
    out: dict = {}
    groups: dict = {}
    if not shape_keys:
        w = r.length_(r.get(t, "tissue", "width", required=True), "tissue.width", positive=True)
        h = r.length_(r.get(t, "tissue", "height", required=True), "tissue.height", positive=True)
        out.update(width=w, height=h)
        outline = geo.rectangle_polygon((0.0, 0.0), (w, h))
    else:
        if shape_keys[0] == "mesh":
            outline, groups = _read_tissue_mesh(r, t["mesh"], "needle")
        else:
            outline = r.points(t["outline"], "tissue.outline")
            if len(outline) < 3:
                r.fail("tissue.outline", "need at least 3 vertices")
            try:
                geo.check_simple_polygon(outline, "tissue.outline")
            except InvalidInputError as exc:
                r.fail("tissue.outline", str(exc).removeprefix("tissue.outline: "))
            if geo.polygon_area(outline) <= 0:
                r.fail("tissue.outline", "must be counter-clockwise with a positive area")
        out["outline"] = outline
    n = len(outline)
    scale = float(np.ptp(outline, axis=0).max())
    segs = []
    if "fixed_vertices" in t:
        for i, p in enumerate(r.points(t["fixed_vertices"], "tissue.fixed_vertices")):
            if np.sqrt(((outline - p) ** 2).sum(1)).min() > 1e-9 * scale:
                r.fail(f"tissue.fixed_vertices[{i}]", "must be a vertex of the outline")
            segs.append(np.stack([p, p]))
    if "fixed_edges" in t:
        e = t["fixed_edges"]
        if not isinstance(e, list) or not e:
            r.fail("tissue.fixed_edges", f"expected a list of edge indices, got {e!r}")
        for i, k in enumerate(e):
            k = r.integer(k, f"tissue.fixed_edges[{i}]", 0)
            if k >= n:
                r.fail(
                    f"tissue.fixed_edges[{i}]", f"expected an edge index in [0, {n - 1}], got {k}"
                )
            segs.append(np.stack([outline[k], outline[(k + 1) % n]]))
    if "fixed_group" in t:
        g = t["fixed_group"]
        if "mesh" not in t:
            r.fail("tissue.fixed_group", "names a group of the tissue.mesh file; there is none")
        if not isinstance(g, str) or g not in groups:
            known = ", ".join(sorted(groups)) or "none"
            r.fail("tissue.fixed_group", f"no group {g!r} in the mesh file (its groups: {known})")
        segs.extend(groups[g])
    region = None
    if "fixed_region" in t:
        v = t["fixed_region"]
        if not isinstance(v, dict):
            r.fail("tissue.fixed_region", "expected a table {lo, hi}")
        r.check_keys(v, _RECT, "tissue.fixed_region")
        lo = r.point(r.get(v, "tissue.fixed_region", "lo", required=True), "tissue.fixed_region.lo")
        hi = r.point(r.get(v, "tissue.fixed_region", "hi", required=True), "tissue.fixed_region.hi")
        if not (hi[0] >= lo[0] and hi[1] >= lo[1]):
            r.fail("tissue.fixed_region", f"hi {hi} must not be below lo {lo}")
        region = np.array([lo, hi])
    if segs or region is not None:
        # the fixed set must hold the tissue: at least two distinct points of the outline
        pts = np.concatenate([np.reshape(segs, (-1, 2))] if segs else [np.zeros((0, 2))])
        if region is not None:
            pts = np.concatenate([pts, _clip_outline(outline, region)])
        if len(np.unique(np.round(pts / (1e-9 * scale)), axis=0)) < 2:
            r.fail(
                "tissue",
                "the fixed boundary holds fewer than two distinct points of the outline (fixed "
                "vertices, edge ends, or outline inside fixed_region): the tissue could move "
                "rigidly",
            )
        out["fixed_segments"] = np.asarray(segs, dtype=np.float64).reshape(-1, 2, 2)
        out["fixed_region"] = region
    return out
