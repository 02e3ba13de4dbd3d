"""The camera's pose in ``hand_base`` at a time, from ``/tf`` and ``/tf_static`` (a tf2 tree).

Every edge (parent -> child) is a series of stamped transforms; a static edge holds one, valid
at all times. ``lookup(target, source, t_ns)`` composes the edges between the two frames,
each at its latest transform stamped at or before ``t_ns`` (never a later one, as everywhere in
the import), and returns the pose of ``source`` in ``target`` and the stamp of the oldest
dynamic transform it used (None if only static ones were used).
"""

from __future__ import annotations

import numpy as np

from hingelab.ros2.ros_messages import frame_name, stamp_ns, transform_pose


class TfTree:
    def __init__(self):
        self._parent: dict[str, str] = {}
        self._static: dict[str, tuple] = {}  # child -> (R, t)
        self._dynamic: dict[str, list] = {}  # child -> [(stamp, R, t)], then arrays after finish()
        self.reparented = 0  # transforms naming a second parent for a frame (tf2 keeps one): ignored

    def add(self, tf_message, static: bool) -> None:
        for tr in tf_message.transforms:
            parent, child = frame_name(tr.header.frame_id), frame_name(tr.child_frame_id)
            if self._parent.setdefault(child, parent) != parent:
                self.reparented += 1
                continue
            pose = transform_pose(tr.transform)
            if static:
                self._static[child] = pose
            else:
                self._dynamic.setdefault(child, []).append((stamp_ns(tr.header.stamp), *pose))

    def finish(self) -> None:
        """Sort every dynamic edge by stamp (bags may hold them out of order)."""
        for child, series in self._dynamic.items():
            series.sort(key=lambda s: s[0])
            self._dynamic[child] = (np.array([s[0] for s in series], np.int64), [s[1:] for s in series])

    @property
    def frames(self) -> set[str]:
        return set(self._parent) | set(self._parent.values())

    def _chain(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self._parent and len(chain) < 64:
            chain.append(self._parent[chain[-1]])
        return chain

    def _edge(self, child: str, t_ns: int):
        """(R, t, stamp or None) of child in its parent at t_ns; None if no transform yet."""
        if child in self._static:
            return (*self._static[child], None)
        stamps, poses = self._dynamic[child]
        i = int(np.searchsorted(stamps, t_ns, side="right")) - 1
        return None if i < 0 else (*poses[i], int(stamps[i]))

    def _to_root(self, chain: list[str], t_ns: int):
        rot, pos, oldest = np.eye(3), np.zeros(3), None
        for child in chain[:-1]:
            edge = self._edge(child, t_ns)
            if edge is None:
                return None
            r, p, stamp = edge
            rot, pos = r @ rot, r @ pos + p  # child -> parent, composed onto what is below
            if stamp is not None:
                oldest = stamp if oldest is None else min(oldest, stamp)
        return rot, pos, oldest

    def lookup(self, target: str, source: str, t_ns: int):
        """(R, t, oldest dynamic stamp) of ``source`` in ``target`` at ``t_ns``; a str saying why if none."""
        target, source = frame_name(target), frame_name(source)
        if target == source:
            return np.eye(3), np.zeros(3), None
        up_source, up_target = self._chain(source), self._chain(target)
        common = next((f for f in up_source if f in up_target), None)
        if common is None:
            return f"no transform connects {source!r} to {target!r}"
        a = self._to_root(up_source[:up_source.index(common) + 1], t_ns)
        b = self._to_root(up_target[:up_target.index(common) + 1], t_ns)
        if a is None or b is None:
            return f"no transform between {source!r} and {target!r} stamped at or before this time"
        (ra, pa, sa), (rb, pb, sb) = a, b
        stamps = [s for s in (sa, sb) if s is not None]
        return rb.T @ ra, rb.T @ (pa - pb), (min(stamps) if stamps else None)


__all__ = ["TfTree"]
