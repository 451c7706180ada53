"""The one place that knows the key expressions.

Layout, under ``twin/<scene>/``::

    scene                       SceneInfo: table and end effector (queryable: what a late joiner asks first)
    objects/<id>/cloud          Cloud: when an object appears or changes (also answered by the queryable)
    objects/<id>/pose           Pose: when the remote pose leaves the deadband (also answered by the queryable)
    objects/<id>/gone           Gone: the object left the scene
    remote/heartbeat            Heartbeat: a few times a second, so silence can be told from stillness
    operator/command            OperatorCommand: the operator's end-effector target, local -> remote
    operator/target             OperatorTarget: a device driver's end-effector target, device -> local twin
                                (``twin local --operator-topic``)
    operator/force              OperatorForce: the force the operator should feel, local twin -> device
                                (newtons, world axes, at the loop rate or ``--force-rate``)

A device driver (a haptic device, a joystick, a script) needs only these two keys and the two message
types of :mod:`sync.messages`: it publishes ``OperatorTarget`` on ``twin/<scene>/operator/target`` and
subscribes to ``twin/<scene>/operator/force``. The twin checks every target like any other message
(finite, within 1 km, then within the scene's workspace) and drops the rest.

Object ids are restricted to ``[A-Za-z0-9_-]`` by the scene format, so they are safe key chunks.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache

PREFIX = "twin"
#: Longest id (scene, object, device), characters; other names on the wire (materials) are held to it too.
MAX_ID_LENGTH = 64
#: An id (scene, object, device), as a regular expression in both Python's and JSON Schema's (ECMA) dialects: the
#: scene file's schema uses it too. ``$(?!\n)``: Python's ``$`` also matches before a final newline, and "obj1\n"
#: passed as an id (a MuJoCo body and a Zenoh key of its own); in ECMA ``$`` is the end and the lookahead a no-op.
ID_PATTERN = rf"^[A-Za-z0-9_-]{{1,{MAX_ID_LENGTH}}}$(?!\n)"
_CHUNK = re.compile(ID_PATTERN)


def valid_id(name: str) -> bool:
    """Whether ``name`` may be a scene or object id: 1-64 of ``[A-Za-z0-9_-]`` (a safe key chunk)."""
    return isinstance(name, str) and _CHUNK.match(name) is not None
OBJECT_KINDS = ("cloud", "pose", "gone")


@dataclass(frozen=True)
class Keys:
    """Key expressions for one scene."""

    scene: str

    def __post_init__(self) -> None:
        if not valid_id(self.scene):
            raise ValueError(f"scene name {self.scene!r} is not a valid key chunk ([A-Za-z0-9_-], 1-64)")

    @property
    def root(self) -> str:
        return f"{PREFIX}/{self.scene}"

    @property
    def info(self) -> str:
        return f"{self.root}/scene"

    def object(self, object_id: str, kind: str) -> str:
        if kind not in OBJECT_KINDS or not valid_id(object_id):
            raise ValueError(f"bad object key: {object_id!r}/{kind!r}")
        return f"{self.root}/objects/{object_id}/{kind}"

    @property
    def objects(self) -> str:
        """Every object message (subscribe here)."""
        return f"{self.root}/objects/**"

    @property
    def state(self) -> str:
        """What a late joiner asks for: clouds and poses of every current object."""
        return f"{self.root}/objects/*/*"

    @property
    def heartbeat(self) -> str:
        return f"{self.root}/remote/heartbeat"

    @property
    def operator(self) -> str:
        return f"{self.root}/operator/command"

    @property
    def operator_target(self) -> str:
        """Where a device driver publishes :class:`sync.messages.OperatorTarget` for the twin to follow."""
        return f"{self.root}/operator/target"

    @property
    def operator_force(self) -> str:
        """Where the twin publishes :class:`sync.messages.OperatorForce`, the force to render."""
        return f"{self.root}/operator/force"

    def parse_object(self, key: str) -> tuple[str, str] | None:
        """(object id, kind) of an object key of this scene, else None."""
        parts = key.split("/")
        if len(parts) == 5 and parts[:3] == [PREFIX, self.scene, "objects"] and parts[4] in OBJECT_KINDS:
            return parts[3], parts[4]
        return None


#: The message each non-object key carries, by its chunks after ``twin/<scene>/``: the message's tag in
#: :mod:`sync.messages` (object keys ``objects/<id>/<kind>`` carry the message tagged ``<kind>``).
_CARRIES = {("scene",): "scene", ("remote", "heartbeat"): "heartbeat", ("operator", "command"): "operator",
            ("operator", "target"): "target", ("operator", "force"): "force"}


def carried_by(key: str) -> tuple[str, str, str | None] | None:
    """(scene, the tag of the one message type ``key`` carries, the object id in it or None) for a key of the
    layout above, exactly; None for any other key (deeper, shallower, unknown chunks, a bad id)."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != PREFIX or not valid_id(parts[1]):
        return None
    rest = tuple(parts[2:])
    if len(rest) == 3 and rest[0] == "objects" and rest[2] in OBJECT_KINDS and valid_id(rest[1]):
        return parts[1], rest[2], rest[1]
    tag = _CARRIES.get(rest)
    return None if tag is None else (parts[1], tag, None)


def any_scene_info() -> str:
    """Selector for the scene info of every scene on the network (discovery)."""
    return f"{PREFIX}/*/scene"


def scene_of(key: str) -> str:
    """The scene name in a key under ``twin/<scene>/``."""
    parts = key.split("/")
    if len(parts) < 2 or parts[0] != PREFIX:
        raise ValueError(f"not a tactile-twin key: {key!r}")
    return parts[1]


def intersects(a: str, b: str) -> bool:
    """Whether two key expressions share at least one key, as Zenoh matches them.

    ``*`` stands for exactly one chunk, ``**`` for any number of chunks (none included). Used by the
    in-process transport; Zenoh does its own matching.
    """
    return _intersects(tuple(a.split("/")), tuple(b.split("/")))


#: Key pairs whose match is remembered: the in-process bus matches every message's key against every
#: subscription, and forged unique keys must not grow the memo without limit (100k of them held ~350 MB).
_MATCH_MEMO = 65_536


@lru_cache(maxsize=_MATCH_MEMO)
def _intersects(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    # Bottom-up over suffixes, not recursion: a forged key of a few thousand chunks would pass Python's
    # recursion limit. ``rest[j]``: whether a[i:] and b[j:] intersect, for the current i.
    la, lb = len(a), len(b)
    rest = [False] * (lb + 1)
    rest[lb] = True
    for j in range(lb - 1, -1, -1):
        rest[j] = rest[j + 1] and b[j] == "**"
    for i in range(la - 1, -1, -1):
        below = rest  # a[i + 1:] against every b[j:]
        rest = [False] * (lb + 1)
        rest[lb] = a[i] == "**" and below[lb]
        for j in range(lb - 1, -1, -1):
            x, y = a[i], b[j]
            if x == "**":
                rest[j] = below[j] or rest[j + 1]
            elif y == "**":
                rest[j] = rest[j + 1] or below[j]
            else:
                rest[j] = (x == y or x == "*" or y == "*") and below[j + 1]
    return rest[0]
