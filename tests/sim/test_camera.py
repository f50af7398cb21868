"""The simulated RGB-D camera against the building it looks at."""

from __future__ import annotations

import numpy as np
import pytest

from mfmap.sim.boxes import Box, Kind, cast_rays
from mfmap.sim.camera import CAMERA_MOUNT, RgbdCamera, RgbdSpec, box_colours, surface_colour
from mfmap.sim.run import build_trajectory
from mfmap.sim.scenarios import SCENARIOS, building_for
from mfmap.sim.sensors import Scenes
from mfmap.sim.trajectory import rotation_matrices


@pytest.fixture(scope="module")
def corridor() -> Scenes:
    spec = SCENARIOS["corridor-rgbd"]
    building = building_for(spec, 0)
    return Scenes(building, build_trajectory(spec, building, 0, 1))


def _truth(scenes: Scenes, cam: RgbdCamera, t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free optical z, |cos incidence| and box colour per pixel."""
    xyz, rpy = scenes.traj.interp(np.array([t_s]))
    rot = rotation_matrices(rpy)[0]
    rays = np.empty((cam.dirs.shape[0], 6), dtype=np.float32)
    rays[:, :3] = xyz[0] + rot @ np.array(CAMERA_MOUNT.xyz)
    rays[:, 3:] = cam.dirs @ (rot @ CAMERA_MOUNT.rotation).T
    b = scenes.building
    open_floor = scenes.traj.door_open_at(t_s)
    r, ids, n = cast_rays(b.scene(open_floor), rays)
    boxes = b.static_boxes() + [b.landing_door(k) for k in range(b.n_floors) if k != open_floor]
    colours = box_colours(boxes)[np.minimum(ids, len(boxes) * 12 - 1) // 12]
    cos = np.abs((n * rays[:, 3:]).sum(axis=1))
    return r * cam.z_per_m, cos, colours


def test_depth_noise_grows_with_range_and_grazing_surfaces_are_holes(corridor: Scenes) -> None:
    spec = RgbdSpec()
    cam = RgbdCamera(spec, corridor, seed=3)
    near_err, far_err, grazing_valid, valid_all = [], [], [], []
    for t_s in np.arange(10.0, 40.0, 1.5):
        depth, _ = cam.capture(float(t_s))
        z, cos, _ = _truth(corridor, cam, float(t_s))
        mm = depth.reshape(-1).astype(float) / 1000.0
        ok = mm > 0
        valid_all.append(ok.mean())
        err = mm[ok] - z[ok]
        near_err += err[z[ok] < 1.5].tolist()
        far_err += err[(z[ok] > 3.5) & (z[ok] < 5.0)].tolist()
        grazing_valid += ok[np.isfinite(z) & (cos < spec.grazing_cos)].tolist()
    assert 0.5 < np.mean(valid_all) < 0.99
    near_sd, far_sd = float(np.std(near_err)), float(np.std(far_err))
    assert near_sd < 0.004 and 0.008 < far_sd < 0.03, (near_sd, far_sd)
    assert abs(float(np.mean(far_err))) < 0.003  # unbiased
    assert len(grazing_valid) > 20 and not any(grazing_valid)


def test_each_pixel_shows_its_surface_colour(corridor: Scenes) -> None:
    cam = RgbdCamera(RgbdSpec(), corridor, seed=3)
    _, rgb = cam.capture(20.0)
    z, _, colours = _truth(corridor, cam, 20.0)
    seen = np.isfinite(z)
    assert seen.mean() > 0.9
    np.testing.assert_array_equal(rgb.reshape(-1, 3)[seen], colours[seen])
    # Neighbouring surfaces differ: the image holds several colours.
    assert len(np.unique(rgb.reshape(-1, 3)[seen], axis=0)) >= 4


def test_surface_colour_is_the_boxes_own() -> None:
    a = Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), Kind.WALL)
    b = Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.01), Kind.WALL)
    assert surface_colour(a) == surface_colour(Box(a.lo, a.hi, a.kind))
    assert surface_colour(a) != surface_colour(b)
