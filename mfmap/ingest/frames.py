"""Where each sensor sits on the robot: the log's transforms and the config's, put together."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mfmap.errors import MissingDataError
from mfmap.ingest.core import LogCore
from mfmap.ingest.extrinsics import Edge, TfSeen, config_edges, connect, missing_message
from mfmap.ingest.series import SeriesReader
from mfmap.ingest.tfread import TfStore
from mfmap.types import Extrinsics, Role

# Sensors whose pose in the base a map cannot do without (the barometer's only shifts every
# pressure alike, which the floors stage does not see).
_NEEDED_FRAMES = (Role.LIDAR, Role.SCAN2D, Role.IMU)


class Frames:
    """The sensors' poses in the base frame, and where each one comes from."""

    def __init__(self, core: LogCore, series: SeriesReader, tf: TfStore,
                 first_frame: Callable[[Role], str | None]) -> None:
        self._core = core
        self._series = series
        self._tf = tf
        self._first_frame = first_frame
        self._extrinsics: Extrinsics | None = None
        self.sources: dict[str, str] = {}

    def transforms(self, alone: bool = False) -> tuple[list[Edge], TfSeen]:
        """The transforms of /tf_static, and what /tf holds: read with the other small streams
        in their one pass, or with `alone` by themselves (a few messages, or for /tf one entry
        per frame pair however long the log)."""
        if self._tf.read is None and not alone:
            self._series.read()
        if self._tf.read is None and self._tf.pending is not None:
            self._tf.read = self._tf.pending.result()  # a transform message that failed raises here
        if self._tf.read is None:
            tf = self._tf.reader()
            topics = self._tf.topics()
            for raw in self._core._iter_raw(topics, None, None) if topics else iter(()):
                tf.add(raw)
            self._tf.read = tf.result()
        return self._tf.read

    def _sensor_frames(self) -> dict[str, list[str]]:
        """Frame of each sensor the build uses -> its roles (a 2D laser only without a 3D one)."""
        out: dict[str, list[str]] = {}
        for role in (Role.LIDAR, Role.SCAN2D, Role.IMU, Role.BARO):
            if role == Role.SCAN2D and Role.LIDAR in self._core.roles:
                continue
            frame = self._first_frame(role)
            if frame is None:
                continue
            out.setdefault(frame.lstrip("/"), []).append(role.value)
        return out

    def frame_status(self, alone: bool = False) -> tuple[Extrinsics, dict[str, str], list[str]]:
        """(extrinsics, where each sensor frame's transform comes from, problems): a problem is
        the one-line reason a needed sensor frame has no transform to the base. `alone` reads
        the transforms by themselves, not in the small streams' pass."""
        base = self._core.config.base_frame.lstrip("/")
        log_edges, seen = self.transforms(alone)
        edges = [*log_edges, *seen.static_edges(), *config_edges(self._core.config.extrinsics)]
        tree = connect(base, edges)
        poses = {f: p for f, p in tree.poses.items() if f != base}
        sources: dict[str, str] = {}
        missing: dict[str, list[str]] = {}
        optional: dict[str, list[str]] = {}
        for frame, roles in self._sensor_frames().items():
            if frame in ("", base):
                sources[frame or base] = "base"
                continue
            if frame in tree.poses:
                sources[frame] = tree.sources[frame]
                continue
            needed = any(Role(r) in _NEEDED_FRAMES for r in roles)
            (missing if needed else optional)[frame] = roles
        problems: list[str] = []
        searched = " and ".join(
            t for t in ([self._core.roles[Role.TF_STATIC]] if Role.TF_STATIC in self._core.roles else [])
            + self._tf.tf_topics) or "the log (it has no /tf_static or /tf)"
        if missing:
            message = missing_message(base, missing, tree, searched, edges, seen.moving())
            if self._core.config.assume_identity_extrinsics:
                self._core._warn(f"{message.split(': give')[0]}: placed at the base with no "
                                 "rotation (--assume-identity-extrinsics)")
                for frame in missing:
                    sources[frame] = "identity (assumed)"
                    poses[frame] = np.eye(4)
            else:
                problems.append(message)
                for frame in missing:
                    sources[frame] = "missing"
        for frame, roles in optional.items():
            self._core._warn(
                f"no transform from '{base}' to frame '{frame}' ({', '.join(roles)}): placed at "
                "the base (a barometer's offset shifts every pressure alike, which the floors do "
                "not see)")
            sources[frame] = "identity (not needed)"
            poses[frame] = np.eye(4)
        self.sources = sources
        return Extrinsics(base_frame=self._core.config.base_frame, sensor_to_base=poses), sources, problems

    def extrinsics(self) -> Extrinsics:
        """Pose in `config.base_frame` of every frame the log's static transforms (/tf_static,
        and pairs that never change on /tf) and `config.extrinsics` connect to it.

        A lidar, 2D laser or IMU frame left unconnected raises MissingDataError naming the
        frames and the ways out, unless `assume_identity_extrinsics` (then identity, a warning).
        """
        if self._extrinsics is not None:
            return self._extrinsics
        extrinsics, _, problems = self.frame_status()
        if problems:
            raise MissingDataError(problems[0], self._core.path)
        self._extrinsics = extrinsics
        return extrinsics

