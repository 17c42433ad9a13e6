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
import numbers
from dataclasses import asdict, dataclass

import numpy as np

from riskplan._validation import as_array, as_generator, check_count
from riskplan.errors import InvalidInputError


def _pixel_count(value, name: str) -> int:
    """``value`` as a positive ``int`` (integral floats such as ``640.0`` are accepted)."""
    return check_count(value, name, 1, integral=True, noun="pixel count")


def _real(value, name: str, what: str = "a finite number") -> float:
    """``value`` as a finite ``float``; raises :class:`InvalidInputError` naming ``name``."""
    if (
        isinstance(value, bool)
        or not isinstance(value, numbers.Real)
        or not math.isfinite(float(value))
    ):
        raise InvalidInputError(f"{name}: expected {what}, got {value!r}")
    return float(value)


def _fov(value, name: str) -> float:
    """A field of view in degrees, ``0 < value < 180``."""
    v = _real(value, name, "a field of view in degrees, 0 < fov < 180")
    if not 0.0 < v < 180.0:
        raise InvalidInputError(
            f"{name}: expected a field of view in degrees, 0 < fov < 180, got {value!r}"
        )
    return v


def _check_samples(points, normals) -> tuple[np.ndarray, np.ndarray]:
    """Surface samples ``points (N, 3)`` and ``normals (N, 3)``: finite, same length."""
    p = as_array(points, "points", shape=(None, 3))
    n = as_array(normals, "normals", shape=(None, 3))
    if len(n) != len(p):
        raise InvalidInputError(
            f"normals: expected one normal per point ({len(p)}), got shape {n.shape}"
        )
    return p, n


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole depth camera.

    ``position (3,)`` is the camera centre and ``rotation (3, 3)`` has as columns the camera
    axes (x right, y down, z viewing direction), both in the robot base frame (m).
    Intrinsics in pixels; depth noise std in m (constant part) and 1/m (quadratic part).
    ``width``/``height`` must be positive integers (integral floats are stored as ``int``);
    every other number must be finite, except ``max_depth`` which may be ``inf`` (no far limit).
    Invalid values raise :class:`~riskplan.errors.InvalidInputError` naming the field.
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
        try:
            R = np.asarray(self.rotation, dtype=float)
            p = np.asarray(self.position, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f"position/rotation: expected numbers ({exc})") from exc
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InvalidInputError(f"position: expected 3 finite numbers, got {self.position!r}")
        if (
            R.shape != (3, 3)
            or not np.all(np.isfinite(R))
            or not np.allclose(R.T @ R, np.eye(3), atol=1e-9)
            or np.linalg.det(R) <= 0
        ):
            raise InvalidInputError(
                "rotation: expected a proper 3x3 rotation matrix (columns = camera axes)"
            )
        # normalise in place (frozen dataclass): pixel counts to int, the rest to float
        for name in ("width", "height"):
            object.__setattr__(self, name, _pixel_count(getattr(self, name), name))
        for name in ("fx", "fy"):
            v = _real(getattr(self, name), name, "a positive finite focal length in pixels")
            if not v > 0:
                raise InvalidInputError(
                    f"{name}: expected a positive finite focal length in pixels, got {v}"
                )
            object.__setattr__(self, name, v)
        for name in ("cx", "cy"):
            object.__setattr__(
                self, name, _real(getattr(self, name), name, "a finite principal point in pixels")
            )
        for name in ("depth_noise_std", "depth_noise_quadratic"):
            v = _real(getattr(self, name), name, "a finite noise std >= 0")
            if v < 0:
                raise InvalidInputError(f"{name}: expected a finite noise std >= 0, got {v}")
            object.__setattr__(self, name, v)
        lo = _real(self.min_depth, "min_depth", "a finite depth in m")
        if isinstance(self.max_depth, bool) or not isinstance(self.max_depth, numbers.Real):
            raise InvalidInputError(f"max_depth: expected a depth in m, got {self.max_depth!r}")
        hi = float(self.max_depth)
        if not 0 < lo < hi:  # also rejects a NaN max_depth; inf means no far limit
            raise InvalidInputError(
                f"min_depth/max_depth: expected 0 < min < max, got {self.min_depth}, {self.max_depth}"
            )
        object.__setattr__(self, "min_depth", lo)
        object.__setattr__(self, "max_depth", hi)

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
    def look_at(
        cls,
        position,
        target,
        up=(0.0, 0.0, 1.0),
        *,
        width: int = 640,
        height: int = 480,
        hfov_deg: float = 87.0,
        vfov_deg: float | None = None,
        **kwargs,
    ) -> PinholeCamera:
        """Camera at ``position`` looking at ``target`` with image-up close to ``up`` (base frame).

        Focal lengths from the field of view: ``fx = (width / 2) / tan(hfov / 2)``, likewise
        ``fy`` from ``vfov``; without ``vfov_deg`` the pixels are square (``fy = fx``). Fields of
        view must satisfy ``0 < fov < 180`` (degrees).
        """
        width = _pixel_count(width, "width")
        height = _pixel_count(height, "height")
        hfov_deg = _fov(hfov_deg, "hfov_deg")
        if vfov_deg is not None:
            vfov_deg = _fov(vfov_deg, "vfov_deg")
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
        return cls(
            tuple(float(v) for v in c),
            tuple(tuple(float(v) for v in row) for row in R),
            width,
            height,
            fx,
            fy,
            0.5 * (width - 1),
            0.5 * (height - 1),
            **kwargs,
        )

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
            raise InvalidInputError(
                f"camera: expected keys {sorted(cls.__dataclass_fields__)}, got {sorted(d)}"
            )
        try:
            d["position"] = tuple(float(v) for v in d["position"])
            d["rotation"] = tuple(tuple(float(v) for v in r) for r in d["rotation"])
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f"camera: position/rotation must be numbers ({exc})") from exc
        return cls(**d)

    def pixel_footprint(self, depth: float) -> float:
        """Side of one pixel's footprint (m) at ``depth`` (the larger of x and y)."""
        return depth / min(self.fx, self.fy)


def default_cameras(
    distance: float = 0.4, height: float = 0.1, azimuth_deg: float = 90.0, **kwargs
) -> tuple[PinholeCamera, PinholeCamera]:
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
        uv = np.stack(
            [camera.fx * q[..., 0] / z + camera.cx, camera.fy * q[..., 1] / z + camera.cy], axis=-1
        )
    return q, uv


def visible_samples(points, normals, camera: PinholeCamera):
    """Indices of the samples the camera sees, one per pixel (the nearest), and their pixels.

    ``points``/``normals``: ``(N, 3)``, finite. Returns ``index (k,)`` into the samples and
    ``pixel (k, 2)`` integer ``(row, col)``. No noise.
    """
    points, normals = _check_samples(points, normals)
    return _visible_samples(points, normals, camera)


def _visible_samples(points: np.ndarray, normals: np.ndarray, camera: PinholeCamera):
    """:func:`visible_samples` on checked float64 arrays."""
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
    points, normals = _check_samples(points, normals)
    return _render(points, normals, camera, as_generator(seed))


def _render(
    points: np.ndarray, normals: np.ndarray, camera: PinholeCamera, rng: np.random.Generator
):
    """:func:`render` on checked float64 arrays."""
    idx, pix = _visible_samples(points, normals, camera)
    p = points[idx]
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

    Each camera draws its noise from its own child of ``seed`` (``None``, an int, a
    ``SeedSequence`` or a ``Generator``; a Generator's children are spawned from its bit
    generator's seed sequence, so the same Generator state always gives the same cloud and
    two calls with one Generator give independent clouds). The merged cloud is reduced to
    ``n_points`` (a positive int) by sampling without replacement (with replacement only if
    fewer points were seen, which the default set-up never produces for the paper robot).
    ``n_points=None`` keeps every point. Returns ``(n_points, 3)`` float64 in the base frame.
    """
    points, normals = _check_samples(points, normals)
    check_count(n_points, "n_points", 1, none=True)
    cams = (cameras,) if isinstance(cameras, PinholeCamera) else cameras
    try:
        cameras = tuple(cams)
    except TypeError:
        cameras = ()
    if not cameras or not all(isinstance(c, PinholeCamera) for c in cameras):
        raise InvalidInputError(
            f"cameras: expected a non-empty sequence of PinholeCamera, got {cameras!r}"
        )
    n_children = len(cameras) + 1
    if isinstance(seed, np.random.Generator):
        ss = getattr(seed.bit_generator, "seed_seq", None)
        if not isinstance(ss, np.random.SeedSequence):  # cannot spawn: seed from the stream itself
            ss = np.random.SeedSequence(seed.integers(2**63, size=4).tolist())
        children = ss.spawn(n_children)
    else:
        try:
            ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(
                f"seed: expected None, a non-negative int, a SeedSequence or a Generator, got {seed!r}"
            ) from exc
        children = ss.spawn(n_children)
    clouds = [
        _render(points, normals, cam, np.random.default_rng(ch))[0]
        for cam, ch in zip(cameras, children)
    ]
    cloud = np.concatenate(clouds, axis=0)
    if n_points is None:
        return cloud
    if len(cloud) == 0:
        raise InvalidInputError("cameras: no camera sees the robot (check the camera poses)")
    rng = np.random.default_rng(children[-1])
    pick = rng.choice(len(cloud), size=n_points, replace=len(cloud) < n_points)
    return cloud[pick]
