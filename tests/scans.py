"""Test scans whose truth is known: depth images of a scene rendered with pybullet's camera, with sensor
noise and holes, back-projected to organized clouds in the sensor's frame and written as PCD, PLY or
XYZ text; an organized cloud triangulated into an open mesh; the truth figures (how many samples
near or far from every scanned point a collision model calls free); and a glTF model kept in several files.
"""
from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from tdgen.robot.surroundings import Surroundings, build_into

NEAR, FAR = 0.005, 0.05  # m: within NEAR of a scanned point must collide; FAR from every point, otherwise free, must not


@dataclass
class Scan:
    """An organized cloud (H, W, 3) in the sensor's optical frame (x right, y down, z ahead), NaN where
    nothing came back, and the sensor's pose in the world (m, fixed-axis rpy in degrees)."""

    points: np.ndarray
    position: tuple[float, float, float]
    rpy: tuple[float, float, float]

    def finite(self) -> np.ndarray:
        flat = self.points.reshape(-1, 3)
        return flat[np.isfinite(flat).all(axis=1)]

    def world(self) -> np.ndarray:
        from scipy.spatial.transform import Rotation

        return Rotation.from_euler("xyz", self.rpy, degrees=True).apply(self.finite()) + np.array(self.position)


def render_scan(scene: Surroundings, eye, target, size=(160, 120), fov=70.0, noise=0.002, holes=0.03,
                seed=0, far=6.0) -> Scan:
    """A depth camera at `eye` looking at `target` (world, m): noise (m, std. dev. along the ray) and
    `holes` (share of pixels lost, half of them in patches), beyond `far` nothing."""
    import pybullet as pb
    from scipy.spatial.transform import Rotation

    width, height = size
    client = pb.connect(pb.DIRECT)
    try:
        build_into(scene, client)
        ahead = np.subtract(target, eye)
        up = [0, 0, 1] if abs(ahead[2]) < 0.99 * np.linalg.norm(ahead) else [0, 1, 0]
        near_plane = 0.05
        view = pb.computeViewMatrix(eye, target, up, physicsClientId=client)
        proj = pb.computeProjectionMatrixFOV(fov, width / height, near_plane, far + 1.0, physicsClientId=client)
        _, _, _, depth, _ = pb.getCameraImage(width, height, view, proj, renderer=pb.ER_TINY_RENDERER,
                                              physicsClientId=client)
    finally:
        pb.disconnect(client)
    d = np.asarray(depth, dtype=float).reshape(height, width)
    z = (far + 1.0) * near_plane / ((far + 1.0) - (far + 1.0 - near_plane) * d)
    rng = np.random.default_rng(seed)
    f = (height / 2) / math.tan(math.radians(fov) / 2)
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    ray = np.dstack([(u - width / 2) / f, (v - height / 2) / f, np.ones_like(u)])
    z = z + rng.normal(0.0, noise, z.shape) / np.linalg.norm(ray, axis=2)
    lost = (z > far) | (rng.random(z.shape) < holes / 2)
    for _ in range(max(1, int(holes * 40))):  # patches: a shiny or black spot returns nothing
        r, c = rng.integers(0, height), rng.integers(0, width)
        lost[r:r + height // 12, c:c + width // 12] = True
    points = ray * z[..., None]
    points[lost] = np.nan
    # optical frame: x right, y down, z ahead; world from the view matrix (OpenGL: x right, y up, -z ahead)
    gl = np.array(view).reshape(4, 4).T  # world -> camera (OpenGL)
    cam_to_world = np.linalg.inv(gl)
    rot = cam_to_world[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    rpy = tuple(float(a) for a in Rotation.from_matrix(rot).as_euler("xyz", degrees=True))
    return Scan(points, tuple(float(p) for p in cam_to_world[:3, 3]), rpy)  # type: ignore[arg-type]


def thinned(scan: Scan, count: int, seed: int = 0) -> Scan:
    """The scan with returns dropped at random (NaN, as a lost return) until `count` are left: a cloud of
    exactly that many points, still organized."""
    flat = scan.points.reshape(-1, 3).copy()
    finite = np.flatnonzero(np.isfinite(flat).all(axis=1))
    if len(finite) < count:
        raise ValueError(f"the scan has {len(finite):,} points, fewer than {count:,}: render it larger")
    flat[np.random.default_rng(seed).choice(finite, len(finite) - count, replace=False)] = np.nan
    return Scan(flat.reshape(scan.points.shape), scan.position, scan.rpy)


def write_pcd(scan: Scan, path: Path, encoding: str = "binary_compressed", extra: bool = True) -> Path:
    """An organized PCD as PCL and ROS write it: NaN points kept, `label` and `rgba` fields beside x y z."""
    from pypcd4 import Encoding, PointCloud

    flat = scan.points.reshape(-1, 3).astype(np.float32)
    if extra:
        label = np.arange(len(flat), dtype=np.uint32) % 7
        rgba = np.full(len(flat), 0xFF808080, dtype=np.uint32)
        cloud = PointCloud.from_points([flat[:, 0], flat[:, 1], flat[:, 2], label, rgba],
                                       ("x", "y", "z", "label", "rgba"),
                                       (np.float32, np.float32, np.float32, np.uint32, np.uint32))
    else:
        cloud = PointCloud.from_xyz_points(flat)
    cloud.metadata.width, cloud.metadata.height = scan.points.shape[1], scan.points.shape[0]
    cloud.save(path, encoding=Encoding(encoding))
    return path


def write_ply(scan: Scan, path: Path, ascii: bool = False) -> Path:
    import trimesh

    trimesh.PointCloud(scan.finite()).export(str(path), encoding="ascii" if ascii else "binary")
    return path


def write_xyz(scan: Scan, path: Path) -> Path:
    np.savetxt(path, scan.finite(), fmt="%.5f", header="x y z", comments="")
    return path


def triangulate(scan: Scan, path: Path, jump: float = 0.05) -> Path:
    """The organized cloud as an open mesh: two triangles per 2x2 block of returns, none across a depth
    jump of more than `jump` (m) (an object's edge against the wall behind it)."""
    import trimesh

    h, w, _ = scan.points.shape
    flat = scan.points.reshape(-1, 3)
    idx = np.arange(h * w).reshape(h, w)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = []
    for tri in ((a, c, b), (b, c, d)):
        t = np.column_stack(tri)
        pts = flat[t]
        ok = np.isfinite(pts).all(axis=(1, 2))
        zs = pts[..., 2]
        ok &= np.nan_to_num(zs.max(axis=1) - zs.min(axis=1), nan=1e9) < jump
        faces.append(t[ok])
    mesh = trimesh.Trimesh(np.nan_to_num(flat), np.vstack(faces), process=False)
    mesh.remove_unreferenced_vertices()
    mesh.export(str(path))
    return path


@dataclass
class Figures:
    """Of the samples: `near` came within NEAR of a scanned point (`near_free` of them called free: must be
    0); `far` kept FAR from every point and were otherwise free (`far_free` called free: >= 99 %)."""

    near: int
    near_free: int
    far: int
    far_free: int

    @property
    def far_share(self) -> float:
        return self.far_free / max(self.far, 1)


class Truth:
    """The robot against the scanned points themselves: a sphere of NEAR and one of FAR around each point
    (pybullet's exact test, the robot's own collision geometry), self-collision from the same world."""

    def __init__(self, robot, placement_scene: Surroundings, points: np.ndarray, rest: Surroundings):
        import pybullet as pb

        from tdgen.robot.collision import CollisionWorld

        self.worlds = {}
        for radius in (NEAR, FAR):
            world = CollisionWorld(robot, rest)
            shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=radius, physicsClientId=world.client)
            for start in range(0, len(points), 4096):
                pb.createMultiBody(0.0, shape, -1, batchPositions=points[start:start + 4096].tolist(),
                                   physicsClientId=world.client)
            self.worlds[radius] = world
        self.free = CollisionWorld(robot, rest)  # without the scan: self-collision and the other bodies

    def touches(self, radius: float, q: np.ndarray) -> bool:
        world = self.worlds[radius]
        world._set(world._values(q[None])[0])
        return any(other != world.body and link not in world._fixed_to_base and other not in world._ids
                   for (link, _), other in world._contacts())

    def figures(self, qs: np.ndarray, called_colliding: np.ndarray) -> Figures:
        near = near_free = far = far_free = 0
        otherwise = self.free.colliding(qs)
        for q, hit, other in zip(qs, called_colliding, otherwise):
            if self.touches(NEAR, q):
                near += 1
                near_free += int(not hit)
            elif not other and not self.touches(FAR, q):
                far += 1
                far_free += int(not hit)
        return Figures(near, near_free, far, far_free)

    def close(self) -> None:
        for world in [*self.worlds.values(), self.free]:
            world.close()


def write_gltf(folder: Path, name: str = "crate", size=(0.4, 0.3, 0.2)) -> Path:
    """`folder/<name>.gltf` with its geometry in `<name>_*.bin` beside it and a texture in `textures/`."""
    files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(trimesh.creation.box(size)))
    gltf = json.loads(files.pop("model.gltf"))
    for k, buffer in enumerate(gltf["buffers"]):
        data = files[buffer["uri"]]
        buffer["uri"] = f"{name}_{k}.bin"
        (folder / buffer["uri"]).write_bytes(data)
    (folder / "textures").mkdir(exist_ok=True)
    png = io.BytesIO()
    Image.new("RGB", (4, 4), (150, 100, 50)).save(png, "PNG")
    (folder / "textures" / "wood grain.png").write_bytes(png.getvalue())
    gltf["images"] = [{"uri": "textures/wood%20grain.png"}]  # a URI: percent-encoded
    path = folder / f"{name}.gltf"
    path.write_text(json.dumps(gltf))
    return path
