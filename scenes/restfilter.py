"""Holding a tracked object still while it rests: each scan's ICP fit averaged with the ones before it.

At rest each scan's fresh noise turned a 3 cm dice by up to 1.4 degrees seen by one camera, and every such
turn past the remote's deadband went out as a correction of an object that had not moved.
:class:`RestFilter` takes a step of ICP for noise when it is small against the object's earlier steps at rest,
and moves the track by the running mean of those fits; a larger step is motion, taken whole.
"""

from __future__ import annotations

import numpy as np

#: A step of ICP that moves no point of the model further than this many times the scatter of the object's
#: earlier steps at rest (their RMS reach), nor this many times the fit's RMS residual, is taken for noise at
#: rest: three sigmas. One noisy camera's fits of a resting box reached 1.5-3 times the residual; a push
#: moves an object centimetres between two scans.
REST_GATE = 3.0

#: Fits at rest a track is the running mean of, at most: eight scans, 4 s at the default period, take the
#: noise of each down by a factor of 2.8; a longer memory would follow a slow creep (under the fit's
#: residual a scan) later.
REST_WINDOW = 8


class RestFilter:
    """Per object, how many fits at rest its track averages and the scatter of its steps at rest.

    Args:
        window: fits averaged at most (1: each scan's own fit, no averaging).
    """

    def __init__(self, window: int = REST_WINDOW) -> None:
        self.window = max(1, int(window))
        self._count: dict[str, int] = {}  # id -> fits averaged into its track since it last moved
        self._scatter: dict[str, tuple[int, float]] = {}  # id -> (steps at rest counted, their mean square reach)
        self._held: set[str] = set()  # ids whose last step was held: past the scatter's gate, not the residual's

    def restart(self, object_id: str) -> None:
        """The object's model changed: the fits averaged so far answered to the old one, and its pose now
        counts as one."""
        self._count[object_id] = 1
        self._held.discard(object_id)

    def forget(self, object_id: str) -> None:
        """The object is seen anew (a new model in a new frame): nothing of its earlier fits counts."""
        self._count.pop(object_id, None)
        self._scatter.pop(object_id, None)
        self._held.discard(object_id)

    def step(self, object_id: str, model: np.ndarray, step: np.ndarray, rmse: float) -> tuple[np.ndarray, float]:
        """``step`` ((4, 4), what ICP found since the last track, acting on the ``model``'s points (n, 3),
        metres), averaged with the fits before it while the object rests; and the factor its uncertainty
        shrinks by.

        A step is noise at rest when it moves no model point further than ``REST_GATE`` times the scatter of
        this object's earlier steps at rest (their RMS reach), and never further than ``REST_GATE`` times the
        fit's RMS residual ``rmse`` (metres: all a first step has to go by). Then the track moves by ``1/n``
        of it, the running mean of the last ``n`` such fits (at most ``window``). After a motion the first is
        the first fit at rest, taken whole (the last fit in motion may have caught it still sliding). The pose
        an object was first seen in counts as ``window - 1`` fits: its model is that view, so while it rests
        that pose is exact, not a noisy fit (counted as one, the first fit at rest moved a 3 cm dice seen by
        one camera by half its 2.4 degree error). A larger step is motion: the track takes it whole and the
        count starts again.

        A step of an object at rest past the scatter's gate but within the residual's is held, once: the
        track stays, and the next step (from the track, so it holds this one's motion too) decides. The fits'
        reach has a long tail: with fits tightened by a model of many scans, a cylinder seen by one camera
        (scatter 0.21 mm) reached 0.87 mm in one scan of 24 and came back the next; taken whole, that one fit
        turned it a degree. A slow push is followed a scan later for it; one past the residual's gate at once.

        The price: a creep slower than the gate a scan is followed up to the gate late. The gate follows the
        scatter because the residual alone let a can's first 2 mm of being pushed (its fits at rest moved it
        0.1-0.4 mm; the residual was 2.5 mm) be averaged away.
        """
        moved = model @ step[:3, :3].T + step[:3, 3] - model
        reach = float(np.sqrt(np.einsum("ij,ij->i", moved, moved).max())) if len(model) else np.inf
        count, scatter = self._scatter.get(object_id, (0, 0.0))
        gate = REST_GATE * (rmse if count < 2 else min(rmse, np.sqrt(scatter)))
        resting = self._count.get(object_id, self.window) > 0
        if resting and gate < reach <= REST_GATE * rmse and object_id not in self._held:
            self._held.add(object_id)
            n = self._count.get(object_id, self.window - 1)
            return np.eye(4), 1.0 / np.sqrt(max(n, 1))
        self._held.discard(object_id)
        if reach > gate:
            self._count[object_id] = 0
            return step, 1.0
        # The scatter's memory is the window too: a new view or noise level shows within a few scans.
        count = min(count + 1, self.window)
        self._scatter[object_id] = (count, scatter + (reach**2 - scatter) / count)
        n = self._count[object_id] = min(self._count.get(object_id, self.window - 1) + 1, self.window)
        return partial_motion(step, model.mean(axis=0), 1.0 / n), 1.0 / np.sqrt(n)

    def resting(self, object_id: str) -> bool:
        """Whether the object's last step was taken for noise at rest (True before its first)."""
        return self._count.get(object_id, self.window) > 0 and object_id not in self._held

    def moved(self, object_id: str) -> bool:
        """Whether the object's last step was taken for motion (not held, nor noise at rest)."""
        return self._count.get(object_id, self.window) == 0 and object_id not in self._held


def partial_motion(step: np.ndarray, centre: np.ndarray, share: float) -> np.ndarray:
    """``share`` (0-1) of the rigid motion ``step`` ((4, 4)): the same turn about ``centre`` ((3,) metres) by
    ``share`` of its angle, and ``share`` of ``centre``'s shift."""
    from scipy.spatial.transform import Rotation

    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(share * Rotation.from_matrix(step[:3, :3]).as_rotvec()).as_matrix()
    shift = step[:3, :3] @ centre + step[:3, 3] - centre
    out[:3, 3] = centre + share * shift - out[:3, :3] @ centre
    return out
