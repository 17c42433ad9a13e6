"""Anatomy from segmentation volumes: a label of a label map becomes a closed surface mesh.

How anatomy reaches a planner: a segmented CT or MR volume (NRRD, NIfTI) holds one integer label
per voxel; the surface of one label, in the volume's physical frame, is an obstacle mesh.

Pipeline (each step a maintained library, no hand-written marching cubes):

1. :func:`read_label_volume` reads the file with SimpleITK, which gives both NRRD and NIfTI in
   one physical frame, ITK's LPS convention (NIfTI's RAS axes are converted on reading). The
   voxel ``(i, j, k)`` (``i`` fastest) has its centre at

   .. math:: x = o + D \\,\\mathrm{diag}(s) \\,(i, j, k)^T

   with origin ``o``, direction cosines ``D`` (columns: the index axes in physical space) and
   spacing ``s``.
2. :func:`label_surface` runs scikit-image's marching cubes (Lewiner) at level 0.5 on the
   binary mask of the label, padded by one voxel so every surface closes, and maps the vertices
   by the equation above times ``scale`` (physical units to metres). For a binary mask the
   level-0.5 surface passes half-way between inside and outside voxel centres: flat faces sit
   exactly on the voxel boundary, edges and corners are cut by at most ``sqrt(3)/2`` voxel.
   Faces are oriented outwards (positive enclosed volume) whatever the handedness of ``D``.
3. :func:`decimate` reduces the triangle count with MeshLab's quadric edge collapse (pymeshlab;
   quadric error metrics, Garland & Heckbert 1997) with topology preservation, and checks that
   the result is still closed and edge-manifold. (fast-simplification, tried first, pinched
   the lab's segmentation, which has 28 handles and 5 mm slices, into non-manifold edges at
   every target from 3k to 20k triangles; MeshLab's topology-preserving collapse did not.)

The mesh stays in the volume's physical frame; where the robot base lies in it is a separate
fact (the sidecar written by :func:`save_segmentation_environment`, see
:mod:`riskplan.collision.mesh_files`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from riskplan.collision.geometry import check_metre_scale
from riskplan.errors import DataFormatError, InvalidInputError, MissingDependencyError

log = logging.getLogger(__name__)

SUFFIXES = (".nrrd", ".nhdr", ".nii", ".nii.gz", ".mha", ".mhd")
# MeshLab's quality threshold of the quadric collapse (its default 0.3: triangles with a worse
# radius ratio are penalised)
DECIMATION_QUALITY = 0.3


@dataclass(frozen=True)
class LabelVolume:
    """A label map and its physical frame.

    Attributes
    ----------
    labels : (K, J, I) integer array, indexed ``[k, j, i]`` (``i`` the fastest file axis).
    spacing : (3,) voxel size along ``i, j, k`` (physical units of the file).
    origin : (3,) physical position of voxel ``(0, 0, 0)``'s centre.
    direction : (3, 3) direction cosines; column ``a`` is index axis ``a`` in physical space.
    path : the file read ("" when built in memory).
    """

    labels: np.ndarray
    spacing: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    path: str = ""

    def __post_init__(self):
        lab = np.asarray(self.labels)
        if lab.ndim != 3 or lab.dtype.kind not in "iub":
            raise InvalidInputError(
                f"labels: expected a 3-D integer array, got shape {lab.shape} dtype {lab.dtype}"
            )
        s = np.asarray(self.spacing, dtype=np.float64)
        o = np.asarray(self.origin, dtype=np.float64)
        D = np.asarray(self.direction, dtype=np.float64)
        if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise InvalidInputError(f"spacing: expected 3 positive numbers, got {self.spacing!r}")
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise InvalidInputError(f"origin: expected 3 finite numbers, got {self.origin!r}")
        if D.shape != (3, 3) or not np.all(np.isfinite(D)) or abs(np.linalg.det(D)) < 1e-6:
            raise InvalidInputError("direction: expected an invertible 3 x 3 matrix")
        for name, v in (("spacing", s), ("origin", o), ("direction", D)):
            v.setflags(write=False)
            object.__setattr__(self, name, v)
        object.__setattr__(self, "labels", lab)

    def index_to_physical(self, ijk) -> np.ndarray:
        """Continuous voxel indices ``(..., 3)`` (``i, j, k``) to physical points ``(..., 3)``:
        ``o + D diag(s) ijk``."""
        return self.origin + (np.asarray(ijk, dtype=np.float64) * self.spacing) @ self.direction.T

    def present_labels(self) -> list[int]:
        """The labels that occur, background 0 excluded."""
        return [int(v) for v in np.unique(self.labels) if v != 0]


def _require(module: str, package: str):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingDependencyError(
            f"{package} is needed to read segmentations: pip install 'riskplan[io]'"
        ) from exc


def read_label_volume(path) -> LabelVolume:
    """Read a label map (``.nrrd``, ``.nhdr``, ``.nii``, ``.nii.gz``, ``.mha``, ``.mhd``) with SimpleITK.

    Raises :class:`InvalidInputError` for a missing file or unknown suffix and
    :class:`DataFormatError` for an unreadable, non-3-D or non-integer volume.
    """
    path = Path(path)
    name = path.name.lower()
    if not any(name.endswith(s) for s in SUFFIXES):
        raise InvalidInputError(
            f"{path}: expected a segmentation volume ending in {', '.join(SUFFIXES)}"
        )
    if not path.is_file():
        raise InvalidInputError(f"segmentation file not found: {path}")
    sitk = _require("SimpleITK", "SimpleITK")
    try:
        image = sitk.ReadImage(str(path))
    except RuntimeError as exc:
        raise DataFormatError(f"{path}: not a readable volume ({str(exc).strip()[:200]})") from exc
    if image.GetDimension() != 3 or image.GetNumberOfComponentsPerPixel() != 1:
        raise DataFormatError(
            f"{path}: expected a 3-D scalar label map, got dimension {image.GetDimension()} "
            f"with {image.GetNumberOfComponentsPerPixel()} components per voxel"
        )
    labels = sitk.GetArrayFromImage(image)  # (k, j, i)
    if labels.dtype.kind not in "iub":
        if not np.all(np.isfinite(labels)) or not np.array_equal(labels, np.round(labels)):
            raise DataFormatError(
                f"{path}: voxel type {labels.dtype} holds non-integer values; expected a label map"
            )
        labels = labels.astype(np.int64)
    return LabelVolume(
        labels=labels,
        spacing=np.array(image.GetSpacing()),
        origin=np.array(image.GetOrigin()),
        direction=np.array(image.GetDirection()).reshape(3, 3),
        path=str(path),
    )


def label_surface(volume: LabelVolume, label: int, *, scale: float = 1.0):
    """Closed surface of ``volume.labels == label`` in the physical frame times ``scale``.

    Parameters
    ----------
    volume : the label map.
    label : the label to mesh; must occur in the volume.
    scale : factor from the file's physical units to metres (0.001 for millimetres).

    Returns
    -------
    vertices : (V, 3) float64, faces : (F, 3) int64 -- outward-oriented, closed.
    """
    if not isinstance(volume, LabelVolume):
        raise InvalidInputError(f"volume: expected a LabelVolume, got {type(volume).__name__}")
    if not (np.isfinite(scale) and scale > 0):
        raise InvalidInputError(f"scale: expected a positive number, got {scale!r}")
    where = f"{volume.path}: " if volume.path else ""
    mask = volume.labels == label
    if not mask.any():
        present = volume.present_labels()
        shown = ", ".join(map(str, present[:20])) + (" ..." if len(present) > 20 else "")
        raise InvalidInputError(
            f"{where}--label {label}: no voxel has this label; labels present: {shown or 'none (empty volume)'}"
        )
    measure = _require("skimage.measure", "scikit-image")
    # crop to the label's bounding box plus a one-voxel zero border: every surface closes
    idx = np.argwhere(mask)
    lo, hi = idx.min(axis=0), idx.max(axis=0) + 1
    sub = np.pad(mask[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]], 1).astype(np.float32)
    verts, faces, _, _ = measure.marching_cubes(sub, level=0.5, method="lewiner")
    kji = verts + (lo - 1)
    V = volume.index_to_physical(kji[:, ::-1]) * float(scale)
    F = faces.astype(np.int64)
    V, F = _clean(V, F)
    if _signed_volume(V, F) < 0:
        F = F[:, ::-1].copy()
    return V, F


def decimate(vertices, faces, target_faces: int):
    """Reduce a closed mesh to ``target_faces`` triangles (quadric edge collapse, topology
    preserved; where keeping the topology needs more triangles, more are kept and logged).

    Returns ``(vertices, faces)`` unchanged when the mesh already has at most that many. Raises
    :class:`InvalidInputError` when the result is no longer closed and edge-manifold (ask for
    more triangles).
    """
    from riskplan.collision.geometry import check_closed_mesh

    target_faces = int(target_faces)
    if target_faces < 4:
        raise InvalidInputError(f"faces: expected at least 4 triangles, got {target_faces}")
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if len(F) <= target_faces:
        return V, F
    pymeshlab = _require("pymeshlab", "pymeshlab")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(V, F))
    # preservetopology: a segmented organ has handles and thin walls (anisotropic slices), and a
    # collapse that pinches them makes the surface non-manifold; planarquadric keeps the many
    # coplanar voxel-face triangles from drifting; qualitythr penalises slivers.
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=target_faces,
        preservetopology=True,
        preservenormal=True,
        planarquadric=True,
        optimalplacement=True,
        qualitythr=DECIMATION_QUALITY,
    )
    m = ms.current_mesh()
    V2, F2 = _clean(
        np.asarray(m.vertex_matrix(), dtype=np.float64),
        np.asarray(m.face_matrix(), dtype=np.int64),
    )
    if len(F2) > target_faces:
        # topology preservation stops collapses that would pinch the surface: the count is
        # reported (info["triangles"], the command's output) rather than forced
        log.warning(
            "decimation stopped at %d triangles (asked for %d): fewer would change the topology",
            len(F2),
            target_faces,
        )
    try:
        check_closed_mesh(V2, F2, "decimated mesh")
    except InvalidInputError as exc:
        raise InvalidInputError(
            f"{exc}; decimating {len(F)} to {target_faces} triangles broke the surface: ask for more triangles"
        ) from None
    if _signed_volume(V2, F2) < 0:
        F2 = F2[:, ::-1].copy()
    return V2, F2


def segmentation_mesh(
    path,
    label: int,
    *,
    faces: int | None = 5000,
    scale: float = 1.0,
    robot_length: float | None = None,
):
    """Read a label map and return ``(vertices (V, 3), faces (F, 3), info)`` of one label's surface,
    decimated to ``faces`` triangles (``None``: not decimated), in metres.

    ``info`` holds the source, label, spacing, origin, direction, scale, the triangle counts and
    the enclosed volume before and after decimation (m^3). With ``robot_length`` the mesh
    extent is checked by :func:`check_metre_scale` before decimation.
    """
    vol = read_label_volume(path)
    V, F = label_surface(vol, int(label), scale=scale)
    if robot_length is not None:
        check_metre_scale(
            V,
            robot_length,
            source=f"{path} label {label}",
            remedy="Scale them by 0.001 (--scale 0.001)",
        )
    info = {
        "source": Path(path).name,
        "label": int(label),
        "spacing": vol.spacing.tolist(),
        "origin": vol.origin.tolist(),
        "direction": vol.direction.tolist(),
        "physical_frame": "ITK LPS (NIfTI RAS converted on reading)",
        "scale_to_metres": float(scale),
        "marching_cubes_triangles": len(F),
        "marching_cubes_volume_m3": _signed_volume(V, F),
    }
    if faces is not None:
        V, F = decimate(V, F, faces)
    info["triangles"] = len(F)
    info["volume_m3"] = _signed_volume(V, F)
    return V, F, info


def save_segmentation_environment(V, F, path, *, info: dict, base_pose=None):
    """Write the mesh and its frame sidecar (:func:`riskplan.collision.mesh_files.save_environment`).

    With ``base_pose`` (the robot base in the volume's physical frame) the sidecar says
    ``"frame": "world"`` with the pose; the string ``"identity"`` declares the volume to be in the
    robot base frame already; ``None`` writes ``"frame": "world"`` without a pose, so a planner
    asks for ``--base-pose`` rather than reading the volume frame as the robot's.
    """
    from riskplan.collision.environment import Environment
    from riskplan.collision.mesh_files import BasePose, save_environment, sidecar_path
    from riskplan.io import write_json_atomic

    env = Environment(V, F, names=[f"label{info['label']}"])
    if isinstance(base_pose, BasePose):
        return save_environment(env, path, base_pose=base_pose, metadata=info)
    if base_pose == "identity":
        return save_environment(env, path, metadata=info)
    if base_pose is not None:
        raise InvalidInputError(
            f"base_pose: expected a BasePose, 'identity' or None, got {base_pose!r}"
        )
    out = save_environment(env, path, metadata=info)
    write_json_atomic(sidecar_path(out), {**info, "frame": "world", "base_pose": None})
    return out


def _clean(V, F):
    """Drop zero-area triangles, back-to-back face pairs and unreferenced vertices.

    Marching cubes on voxel-aligned boundaries can emit zero-area slivers, and quadric edge
    collapse occasionally leaves a "flap": two triangles on the same three vertices, facing
    opposite ways, enclosing no volume. Removing both faces of a flap leaves the rest of the
    surface closed.
    """
    import trimesh

    m = trimesh.Trimesh(V, F, process=True, validate=False)
    m.update_faces(m.nondegenerate_faces())
    F = np.asarray(m.faces, dtype=np.int64)
    _, inverse, counts = np.unique(
        np.sort(F, axis=1), axis=0, return_inverse=True, return_counts=True
    )
    keep = counts[inverse.ravel()] == 1
    if not keep.all():
        log.debug("dropping %d faces of back-to-back pairs", int((~keep).sum()))
        m.update_faces(keep)
    m.remove_unreferenced_vertices()
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def _signed_volume(V, F) -> float:
    """Enclosed volume of a closed triangle mesh, ``sum det(v0, v1, v2) / 6`` (positive when
    faces are outward)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
