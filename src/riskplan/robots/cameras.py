"""Simulated depth cameras: the sensing of the MDN paper's data collection (section III).

The paper records the robot with two RealSense depth cameras on opposite sides and merges
their clouds. We simulate that with pinhole cameras looking at a densely sampled body
surface (:mod:`riskplan.robots.geometry`):

1. *Facing*: a surface sample ``p`` with outward normal ``n`` can be seen only if
   ``n . (c - p) > 0`` (``c`` the camera centre).
2. *Projection* (pinhole): ``q = R^T (p - c)`` in the camera frame (x right, y down,
   z optical axis), pixel ``u = fx q_x / q_z + cx``, ``v = fy q_y / q_z + cy``; samples
   outside the image or the depth range ``[min_depth, max_depth]`` are dropped.
3. *Occlusion* (z-buffer): each pixel returns the nearest facing sample that projects into
   it, so one point per pixel, as a depth camera returns one depth per pixel. The surface
   spacing must be finer than a pixel's footprint (see ``docs/datasets.md``) so that a
   pixel covered by a near surface always holds one of its samples.
4. *Noise along the ray*: the returned range ``|q|`` gets Gaussian noise of std
   ``sigma(z) = depth_noise_std + depth_noise_quadratic * z^2`` (structured-light and
   stereo cameras have an error growing with depth squared), keeping the ray direction.

The cameras' poses are given in the robot base frame, so merged clouds are in the base
frame. Defaults follow a RealSense D435 depth stream: 640 x 480 pixels, 87 deg horizontal
field of view, square pixels (``fx = fy = 337.2``), about 0.5 mm depth noise at 0.4 m.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from riskplan._validation import as_array, as_generator
from riskplan.errors import InvalidInputError


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole depth camera.

    ``position (3,)`` is the camera centre and ``rotation (3, 3)`` has as columns the camera
    axes (x right, y down, z viewing direction), both in the robot base frame (m).
    Intrinsics in pixels; depth noise std in m (constant part) and 1/m (quadratic part).
    """

    position: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...]
    width: int = 640
    height: int = 480
    fx: float = 337.2
    fy: float = 337.2
    cx: float = 319.5
    cy: float = 239.5
    depth_noise_std: float = 0.0005
    depth_noise_quadratic: float = 0.0
    min_depth: float = 0.05
    max_depth: float = 3.0

    def __post_init__(self):
        R = np.asarray(self.rotation, dtype=float)
        p = np.asarray(self.position, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InvalidInputError(f"position: expected 3 finite numbers, got {self.position!r}")
        if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-9) or np.linalg.det(R) <= 0:
            raise InvalidInputError("rotation: expected a proper 3x3 rotation matrix (columns = camera axes)")
        if int(self.width) < 1 or int(self.height) < 1:
            raise InvalidInputError(f"width/height: expected positive pixel counts, got {self.width}x{self.height}")
        for name in ("fx", "fy"):
            if not getattr(self, name) > 0:
                raise InvalidInputError(f"{name}: expected a positive focal length in pixels, got {getattr(self, name)}")
        if self.depth_noise_std < 0 or self.depth_noise_quadratic < 0:
            raise InvalidInputError("depth_noise_std/depth_noise_quadratic: expected >= 0")
        if not 0 < self.min_depth < self.max_depth:
            raise InvalidInputError(f"min_depth/max_depth: expected 0 < min < max, got {self.min_depth}, {self.max_depth}")

    @property
    def R(self) -> np.ndarray:
        return np.asarray(self.rotation, dtype=float)

    @property
    def c(self) -> np.ndarray:
        return np.asarray(self.position, dtype=float)

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix ``(3, 3)``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def look_at(cls, position, target, up=(0.0, 0.0, 1.0), *, width: int = 640, height: int = 480,
                hfov_deg: float = 87.0, vfov_deg: float | None = None, **kwargs) -> PinholeCamera:
        """Camera at ``position`` looking at ``target`` with image-up close to ``up`` (base frame).

        Focal lengths from the field of view: ``fx = (width / 2) / tan(hfov / 2)``, likewise
        ``fy`` from ``vfov``; without ``vfov_deg`` the pixels are square (``fy = fx``).
        """
        c = as_array(position, "position", shape=(3,))
        t = as_array(target, "target", shape=(3,))
        u = as_array(up, "up", shape=(3,))
        z = t - c
        if np.linalg.norm(z) < 1e-12:
            raise InvalidInputError("target: must differ from position")
        z = z / np.linalg.norm(z)
        x = np.cross(z, u)  # image x (right); y = z cross x then points down the image
        if np.linalg.norm(x) < 1e-9:
            raise InvalidInputError("up: must not be parallel to the viewing direction")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z], axis=1)
        fx = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
        fy = fx if vfov_deg is None else 0.5 * height / math.tan(math.radians(vfov_deg) / 2)
        return cls(tuple(float(v) for v in c), tuple(tuple(float(v) for v in row) for row in R), int(width), int(height),
                   fx, fy, 0.5 * (width - 1), 0.5 * (height - 1), **kwargs)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["position"] = list(d["position"])
        d["rotation"] = [list(r) for r in d["rotation"]]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> PinholeCamera:
        d = dict(d)
        unknown = set(d) - set(cls.__dataclass_fields__)
        if unknown or "position" not in d or "rotation" not in d:
            raise InvalidInputError(f"camera: expected keys {sorted(cls.__dataclass_fields__)}, got {sorted(d)}")
        try:
            d["position"] = tuple(float(v) for v in d["position"])
            d["rotation"] = tuple(tuple(float(v) for v in r) for r in d["rotation"])
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f"camera: position/rotation must be numbers ({exc})") from exc
        return cls(**d)

    def pixel_footprint(self, depth: float) -> float:
        """Side of one pixel's footprint (m) at ``depth`` (the larger of x and y)."""
        return depth / min(self.fx, self.fy)


def default_cameras(distance: float = 0.4, height: float = 0.1, azimuth_deg: float = 90.0, **kwargs) -> tuple[PinholeCamera, PinholeCamera]:
    """Two cameras on opposite sides of the robot, ``distance`` m from the base axis at ``height`` m,
    looking horizontally at the axis. ``azimuth_deg`` is the direction of the first camera in the
    base x-y plane (the second is at ``azimuth + 180``). The default (90 deg) puts them on the
    +y and -y sides, ``distance = 0.4`` keeps the whole 0.2 m robot in view at any bend."""
    cams = []
    for a in (azimuth_deg, azimuth_deg + 180.0):
        ar = math.radians(a)
        pos = (distance * math.cos(ar), distance * math.sin(ar), height)
        cams.append(PinholeCamera.look_at(pos, (0.0, 0.0, height), (0.0, 0.0, 1.0), **kwargs))
    return cams[0], cams[1]


def project(points, camera: PinholeCamera):
    """Camera-frame coordinates ``q (..., 3)`` and pixel coordinates ``uv (..., 2)`` of ``points (..., 3)``."""
    q = (np.asarray(points, dtype=np.float64) - camera.c) @ camera.R
    z = q[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([camera.fx * q[..., 0] / z + camera.cx, camera.fy * q[..., 1] / z + camera.cy], axis=-1)
    return q, uv


def visible_samples(points, normals, camera: PinholeCamera):
    """Indices of the samples the camera sees, one per pixel (the nearest), and their pixels.

    ``points``/``normals``: ``(N, 3)``. Returns ``index (k,)`` into the samples and
    ``pixel (k, 2)`` integer ``(row, col)``. No noise.
    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    facing = np.einsum("ij,ij->i", normals, camera.c - points) > 0.0
    idx = np.flatnonzero(facing)
    q, uv = project(points[idx], camera)
    z = q[:, 2]
    ok = (z >= camera.min_depth) & (z <= camera.max_depth)
    col = np.floor(uv[:, 0] + 0.5)  # pixel (i, j) covers [j - 0.5, j + 0.5) around its centre
    row = np.floor(uv[:, 1] + 0.5)
    ok &= (col >= 0) & (col < camera.width) & (row >= 0) & (row < camera.height)
    idx, z, col, row = idx[ok], z[ok], col[ok].astype(np.int64), row[ok].astype(np.int64)
    lin = row * camera.width + col
    # z-buffer: nearest depth per pixel, then among the samples at that depth the first one
    # (a deterministic tie-break); about twice as fast as a lexsort over (pixel, depth).
    zbuf = np.full(camera.width * camera.height, np.inf)
    np.minimum.at(zbuf, lin, z)
    win = np.flatnonzero(z == zbuf[lin])
    _, first = np.unique(lin[win], return_index=True)  # sorted by pixel
    sel = win[first]
    return idx[sel], np.stack([row[sel], col[sel]], axis=1)


def render(points, normals, camera: PinholeCamera, seed=None):
    """The cloud one camera returns: visible samples with range noise, base frame.

    ``points``/``normals``: ``(N, 3)`` surface samples with outward unit normals.
    Returns ``cloud (k, 3)`` (float64, m) and ``pixel (k, 2)``. The noise model is
    ``p' = c + (|p - c| + sigma(z) e) (p - c) / |p - c|``, ``e ~ N(0, 1)``,
    ``sigma(z) = depth_noise_std + depth_noise_quadratic z^2``.
    """
    rng = as_generator(seed)
    idx, pix = visible_samples(points, normals, camera)
    p = np.asarray(points, dtype=np.float64)[idx]
    d = p - camera.c
    r = np.linalg.norm(d, axis=1)
    z = d @ camera.R[:, 2]
    sigma = camera.depth_noise_std + camera.depth_noise_quadratic * z * z
    e = rng.standard_normal(len(r))
    if np.any(sigma > 0):
        p = camera.c + d * ((r + sigma * e) / r)[:, None]
    return p, pix


def depth_image(points, normals, camera: PinholeCamera, seed=None) -> np.ndarray:
    """``(height, width)`` depth image (z along the optical axis, m; ``nan`` where nothing is seen)."""
    cloud, pix = render(points, normals, camera, seed)
    img = np.full((camera.height, camera.width), np.nan)
    img[pix[:, 0], pix[:, 1]] = (cloud - camera.c) @ camera.R[:, 2]
    return img


def capture(points, normals, cameras, n_points: int | None = 512, seed=None) -> np.ndarray:
    """Merged cloud of several cameras, downsampled to ``n_points`` (the paper's 512 per cloud).

    Each camera draws its noise from its own child of ``seed``; the merged cloud is reduced to
    ``n_points`` by sampling without replacement (with replacement only if fewer points were
    seen, which the default set-up never produces for the paper robot). ``n_points=None``
    keeps every point. Returns ``(n_points, 3)`` float64 in the base frame.
    """
    ss = np.random.SeedSequence(seed) if not isinstance(seed, np.random.SeedSequence) else seed
    children = ss.spawn(len(cameras) + 1)
    clouds = [render(points, normals, cam, np.random.default_rng(ch))[0] for cam, ch in zip(cameras, children)]
    cloud = np.concatenate(clouds, axis=0)
    if n_points is None:
        return cloud
    if len(cloud) == 0:
        raise InvalidInputError("cameras: no camera sees the robot (check the camera poses)")
    rng = np.random.default_rng(children[-1])
    pick = rng.choice(len(cloud), size=n_points, replace=len(cloud) < n_points)
    return cloud[pick]
