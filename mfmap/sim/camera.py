"""An RGB-D camera: pinhole ray casting of the building, Kinect-like depth noise, a colour per
surface.

Depth noise grows with the square of the range (the axial noise of structured-light sensors
measured by Nguyen, Izadi and Lovell, "Modeling Kinect Sensor Noise for Improved 3D
Reconstruction and Tracking": 1.2 mm + 1.9 mm (z - 0.4 m)^2), depth is quantised to whole
millimetres (16UC1), and surfaces seen at grazing angles return nothing (the projected pattern
is too stretched to match), as do a few random pixels. The colour image is registered to the
depth (same optical frame and size), jpeg-compressed as a driver publishes it.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mfmap.sim.boxes import Box, Kind, cast_rays
from mfmap.sim.sensors import Mount, Scenes
from mfmap.sim.trajectory import rotation_matrices

F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]


@dataclass(frozen=True)
class RgbdSpec:
    width: int = 80
    height: int = 60
    hfov_deg: float = 58.0  # a Kinect's depth camera
    rate_hz: int = 3
    range_min_m: float = 0.5
    range_max_m: float = 6.0
    noise_a_m: float = 0.0012
    noise_b_per_m: float = 0.0019
    grazing_cos: float = 0.2  # |cos incidence| below this: no return
    dropout: float = 0.01
    jpeg_quality: int = 90

    @property
    def focal_px(self) -> float:
        return 0.5 * self.width / math.tan(math.radians(self.hfov_deg) / 2)

    @property
    def k(self) -> tuple[float, ...]:
        f = self.focal_px
        return (f, 0.0, (self.width - 1) / 2, 0.0, f, (self.height - 1) / 2, 0.0, 0.0, 1.0)


def optical_mount(frame: str, xyz: tuple[float, float, float], pitch_down_deg: float) -> Mount:
    """A camera looking along the base's x axis, tilted down, as an optical frame (z forward,
    x right, y down) in the Mount's roll-pitch-yaw."""
    p = math.radians(pitch_down_deg)
    # The optical axes in the base frame: z = forward tilted down, x = right, y = down-ish.
    z = np.array([math.cos(p), 0.0, -math.sin(p)])
    x = np.array([0.0, -1.0, 0.0])
    y = np.cross(z, x)
    m = np.column_stack([x, y, z])
    pitch = -math.asin(max(-1.0, min(1.0, m[2, 0])))
    roll = math.atan2(m[2, 1], m[2, 2])
    yaw = math.atan2(m[1, 0], m[0, 0])
    mount = Mount(frame, xyz, (roll, pitch, yaw))
    assert np.allclose(mount.rotation, m, atol=1e-9)
    return mount


# On a mast above the base, looking down the corridor: high enough to see table tops from above
# at angles steep enough to return, and the wall cabinets' fronts, both in the robot's height
# band where the 2D scan at 0.3 m sees table legs or nothing.
CAMERA_MOUNT = optical_mount("camera_optical", (0.12, 0.0, 1.1), 20.0)

# Base colours per surface kind; each box varies around its kind's, so neighbouring surfaces
# differ and a colour that came from the wrong surface shows.
_PALETTE = {
    Kind.SLAB: (150, 150, 140),
    Kind.WALL: (205, 195, 170),
    Kind.PILLAR: (110, 115, 130),
    Kind.FURNITURE: (150, 90, 40),
    Kind.STAIRS: (95, 95, 95),
    Kind.DOOR: (120, 70, 40),
    Kind.CABIN_WALL: (180, 185, 190),
    Kind.CABIN_FLOOR: (60, 60, 60),
}


def surface_colour(box: Box) -> tuple[int, int, int]:
    """The paint of a box: its kind's colour shifted by up to +-40 per channel, from its
    corners (the same box always has the same colour)."""
    key = repr((box.kind, *(round(v, 4) for v in (*box.lo, *box.hi)))).encode()
    h = hashlib.sha256(key).digest()
    base = _PALETTE.get(box.kind, (128, 128, 128))
    return tuple(int(np.clip(c + (h[i] % 81) - 40, 0, 255)) for i, c in enumerate(base))  # type: ignore[return-value]


def box_colours(boxes: list[Box]) -> U8:
    return np.array([surface_colour(b) for b in boxes], dtype=np.uint8).reshape(-1, 3)


class RgbdCamera:
    def __init__(self, spec: RgbdSpec, scenes: Scenes, seed: int, mount: Mount = CAMERA_MOUNT) -> None:
        self.spec = spec
        self.scenes = scenes
        self.mount = mount
        self.rng = np.random.default_rng([seed, 29])
        k = spec.k
        vv, uu = np.meshgrid(np.arange(spec.height), np.arange(spec.width), indexing="ij")
        d = np.stack([(uu - k[2]) / k[0], (vv - k[5]) / k[4], np.ones_like(uu, dtype=np.float64)], axis=-1)
        self.z_per_m = 1.0 / np.linalg.norm(d, axis=-1).reshape(-1)  # optical z per metre of ray
        self.dirs = (d / np.linalg.norm(d, axis=-1, keepdims=True)).reshape(-1, 3)
        self._colours: dict[int | None, U8] = {}

    def _scene_colours(self, open_floor: int | None) -> U8:
        if open_floor not in self._colours:
            b = self.scenes.building
            boxes = b.static_boxes() + [b.landing_door(k) for k in range(b.n_floors) if k != open_floor]
            self._colours[open_floor] = box_colours(boxes)
        return self._colours[open_floor]

    def capture(self, t_s: float) -> tuple[npt.NDArray[np.uint16], U8]:
        """Depth in millimetres (0 = no return) and RGB, both (height, width), at time t_s."""
        s = self.spec
        xyz, rpy = self.scenes.traj.interp(np.array([t_s]))
        rot = rotation_matrices(rpy)[0]
        n = self.dirs.shape[0]
        rays = np.empty((n, 6), dtype=np.float32)
        rays[:, :3] = xyz[0] + rot @ np.array(self.mount.xyz)
        rays[:, 3:] = self.dirs @ (rot @ self.mount.rotation).T
        t_arr = np.full(n, t_s)
        r, cos, _ = self.scenes.cast(rays, t_arr, t_s)
        open_floor = self.scenes.traj.door_open_at(t_s)
        r_static, ids, _ = cast_rays(self.scenes.building.scene(open_floor), rays)
        colours = self._scene_colours(open_floor)
        hit = np.isfinite(r_static)
        rgb = np.zeros((n, 3), dtype=np.uint8)
        rgb[hit] = colours[np.minimum(ids[hit] // 12, len(colours) - 1)]
        moving = np.isfinite(r) & (~hit | (r < r_static - 1e-4))  # the cabin, in front of the building
        rgb[moving] = _PALETTE[Kind.CABIN_WALL]
        rng = self.rng
        z = r.astype(np.float64) * self.z_per_m
        sigma = s.noise_a_m + s.noise_b_per_m * np.square(np.maximum(z - 0.4, 0.0))
        z = z + rng.normal(0.0, 1.0, n) * sigma
        valid = np.isfinite(z) & (z >= s.range_min_m) & (z <= s.range_max_m)
        valid &= cos >= s.grazing_cos
        valid &= rng.random(n) >= s.dropout
        mm = np.where(valid, np.round(np.nan_to_num(z, posinf=0.0) * 1000.0), 0.0)
        depth = np.clip(mm, 0, 65535).astype(np.uint16).reshape(s.height, s.width)
        return depth, rgb.reshape(s.height, s.width, 3)
