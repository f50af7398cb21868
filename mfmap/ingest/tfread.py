"""Reading the transform topics: /tf_static's edges, and what /tf holds per frame pair."""

from __future__ import annotations

from pathlib import Path

from mfmap.errors import DecodeError
from mfmap.ingest.backend import Backend, RawMessage
from mfmap.ingest.decode import transform_matrix
from mfmap.ingest.extrinsics import Edge, TfSeen
from mfmap.types import Role

TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")


class TfRead:
    """Collects transform messages: /tf_static's as edges, /tf's per frame pair."""

    def __init__(self, backend: Backend, static: str | None, path: Path) -> None:
        self._backend = backend
        self._path = path
        self.static = static
        self.edges: list[Edge] = []
        self.seen = TfSeen()
        self.error: DecodeError | None = None

    def add(self, raw: RawMessage) -> None:
        if self.error is not None:
            return
        try:
            msg = self._backend.deserialize(raw)
            for tf in msg.transforms:
                parent = str(tf.header.frame_id).lstrip("/")
                child = str(tf.child_frame_id).lstrip("/")
                matrix = transform_matrix(tf.transform)
                if raw.topic == self.static:
                    self.edges.append(Edge(parent, child, matrix, "/tf_static"))
                else:
                    self.seen.add(parent, child, matrix)
        except DecodeError as err:
            self.error = err
        except (AttributeError, TypeError, ValueError) as err:
            self.error = DecodeError(f"unexpected transform message layout ({err})",
                                     f"{self._path} topic {raw.topic}")

    def result(self) -> tuple[list[Edge], TfSeen]:
        if self.error is not None:
            raise self.error
        return self.edges, self.seen


class TfStore:
    """The log's transform topics and, once read, what they hold: read in the small streams'
    one pass (`pending` until asked for) or by themselves."""

    def __init__(self, backend: Backend, roles: dict[Role, str], path: Path) -> None:
        self._backend = backend
        self._path = path
        self.static = roles.get(Role.TF_STATIC)
        # /tf and its kind: every transform topic with messages but the chosen /tf_static.
        self.tf_topics = sorted(
            n for n, t in backend.topics.items()
            if t.msgtype in TF_TYPES and t.count > 0 and n != self.static
        )
        self.read: tuple[list[Edge], TfSeen] | None = None
        self.pending: TfRead | None = None

    def topics(self) -> list[str]:
        """/tf_static (when the log has one) and then the /tf topics."""
        return [t for t in (self.static, *self.tf_topics) if t is not None]

    def reader(self) -> TfRead:
        return TfRead(self._backend, self.static, self._path)
