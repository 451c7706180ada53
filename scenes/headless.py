"""A whole session in one process: the remote scene C and the twin C' on one bus, on a simulated clock.

No sockets, no threads, no waiting: each tick delivers what the network has due, steps the remote, lets the
twin handle what arrived and step, and moves the clock on by one physics step. With ``network=``
(:class:`sync.netem.Network`), messages between the two sides are delayed, lost and queued as configured,
from the network's seed. The same scene, trajectory and seed give the same poses, bit
for bit, and the session runs as fast as the two simulations step.

    with Headless(load_scene("scene.toml")) as session:
        session.run(10.0, trajectory=push)
        print(session.local.twin.pose("mug"))
"""

from __future__ import annotations

import dataclasses
from dataclasses import replace
from pathlib import Path

import numpy as np

from scenes.remote import Remote
from scenes.scenefile import SceneSpec
from scenes.sensing import CameraSensor, Sensor, SurfaceSensor
from sync.clock import SimClock
from sync.inprocess import InProcessBus
from sync.netem import LinkModel, Network
from sync.recording import Recorder, RecordingTransport
from twin.loop import check_duration
from twin.runtime import DEFAULT_LOCAL, NO_OPERATOR_IO, Local, LocalSettings, OperatorSettings
from twin.trajectory import Trajectory


class Headless:
    """Remote and twin of ``scene`` on an :class:`sync.inprocess.InProcessBus` and a :class:`SimClock`.

    The twin joins after the remote has settled and published its scene, estimates every cloud in this
    thread (``workers`` is forced to 0: worker processes would make arrival times depend on the machine),
    and compiles each object before the next tick. ``operator`` is the twin's device input and force output
    (:class:`twin.runtime.OperatorSettings`); ``remote_options`` go to :class:`scenes.remote.Remote`.

    ``network`` puts an emulated link between the sides (``downlink``: remote -> twin, ``uplink``: twin ->
    remote); their counters are ``self.uplink.stats`` and ``self.downlink.stats`` (None: no link that way).
    The twin's late-join query is answered at once (see :mod:`sync.inprocess`); what the remote published
    before the twin joined still crosses the link and arrives as stale duplicates.

    ``record`` (an ``.mcap`` path) records the session (:mod:`sync.recording`): both sides' wire
    messages, the operator's targets and force, and the remote's true poses, on the simulated clock;
    the file is finished by :meth:`close`. Its session metadata names the scene and the remote's ``sensor``
    (:func:`sensor_name`), which ``twin replay`` rebuilds; ``record_metadata`` adds entries to it.

    Raises: TypeError (before any work): ``scene``, ``settings``, ``operator`` or ``network`` of the wrong
    type. :class:`twin.settings.SettingsError`: ``points`` or ``epoch`` among ``remote_options`` out of range
    (:func:`scenes.remote.check_remote_options`; nothing is recorded).
    """

    def __init__(self, scene: SceneSpec, *, settings: LocalSettings = DEFAULT_LOCAL,
                 sensor: Sensor | None = None, cache_dir: Path | None = None, network: Network | None = None,
                 record: str | Path | None = None, record_metadata: dict[str, object] | None = None,
                 operator: OperatorSettings = NO_OPERATOR_IO, **remote_options: object) -> None:
        for name, value, kind, what in (("scene", scene, SceneSpec, "a SceneSpec (load_scene(path) reads one)"),
                                        ("settings", settings, LocalSettings, "a LocalSettings"),
                                        ("operator", operator, OperatorSettings, "an OperatorSettings"),
                                        ("network", network, Network | None, "a sync.netem.Network or None")):
            if not isinstance(value, kind):
                raise TypeError(f"Headless: {name} must be {what}, got {type(value).__name__}")
        self.clock = SimClock()
        self.recorder = None if record is None else Recorder(record, clock=self.clock, metadata={
            **scene_metadata(scene), "side": "both", "command": "headless", "sensor": sensor_name(sensor),
            "network": None if network is None else dataclasses.asdict(network),
            "seeds": {"network": None if network is None else network.seed}, **(record_metadata or {})})
        try:
            self._start(scene, settings, sensor, cache_dir, network, operator, remote_options)
        except BaseException:
            if self.recorder is not None:
                self.recorder.discard()  # nothing ran: no recording, and an earlier file at ``record`` stays
            raise

    def _start(self, scene, settings, sensor, cache_dir, network, operator, remote_options) -> None:  # type: ignore[no-untyped-def]
        self.uplink, self.downlink = (None, None) if network is None else network.models()
        links: dict[tuple[str, str], LinkModel] = {}
        if self.uplink is not None:
            links["twin", "remote"] = self.uplink
        if self.downlink is not None:
            links["remote", "twin"] = self.downlink
        self.bus = InProcessBus(self.clock, links)
        remote_side, twin_side = self.bus.transport("remote"), self.bus.transport("twin")
        if self.recorder is not None:
            remote_side = RecordingTransport(remote_side, self.recorder, "remote")  # type: ignore[assignment]
            twin_side = RecordingTransport(twin_side, self.recorder, "twin")  # type: ignore[assignment]
        self.remote = Remote(scene, remote_side, clock=self.clock, sensor=sensor, cache_dir=cache_dir,
                             recorder=self.recorder, **remote_options)  # type: ignore[arg-type]
        self.dt = float(self.remote.twin.model.opt.timestep)
        self.local = Local(twin_side, clock=self.clock, scene=scene.name, recorder=self.recorder, operator=operator,
                           settings=replace(settings, workers=0, cache_dir=cache_dir or settings.cache_dir))
        if self.local.twin.model.opt.timestep != self.dt:
            raise ValueError("remote and twin step at different rates")  # pragma: no cover

    def __enter__(self) -> Headless:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def tick(self, trajectory: Trajectory | None = None) -> None:
        """Deliver what the network has due now, one physics step of both sides, then the clock moves on.

        Delivering first means a message due at time t is handled by the steps taken at t, so a packet sent
        at t0 over a 50 ms link is seen 50 ms later on the simulated clock (rounded up to a whole step).
        """
        self.bus.deliver_due()
        self.remote.step()
        self.local.iterate(trajectory)
        self.clock.advance(self.dt)

    def run(self, duration: float, *, trajectory: Trajectory | None = None) -> None:
        """Tick for ``duration`` simulated seconds (to a whole physics step); ``trajectory(t)`` is the operator's
        target at twin time t (None from it: no new target).

        Raises:
            LoopError: ``duration`` is not a finite number of seconds at least 0.
        """
        for _ in range(round(check_duration(duration) / self.dt)):
            self.tick(trajectory)

    def poses(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Every twin object's (position, quaternion w x y z), world frame."""
        return {i: self.local.twin.pose(i) for i in self.local.objects}

    def close(self) -> None:
        self.local.close()
        self.remote.close()
        if self.recorder is not None:
            self.recorder.close(twin_time_s=self.local.twin.time)


def scene_metadata(scene: SceneSpec) -> dict[str, object]:
    """What a recording needs to rebuild ``scene``: its name, its file's text and folder (mesh and cloud
    paths in it are relative to that folder); an in-memory scene has no text (replay it with a file)."""
    text = "" if scene.path is None else Path(scene.path).read_text(encoding="utf-8")
    folder = "" if scene.path is None else str(Path(scene.path).resolve().parent)
    return {"scene_name": scene.name, "scene_toml": text, "scene_dir": folder}


#: The remote's sensors by the name ``--sensor`` gives them and a recording's ``sensor`` metadata keeps
#: (:func:`sensor_for`): the surface sensor (:class:`scenes.sensing.SurfaceSensor`, the default) and the scene's
#: default camera rig (:meth:`scenes.sensing.CameraSensor.for_scene`).
SENSORS = ("surface", "cameras")


def sensor_for(name: str, scene: SceneSpec, *, background: bool = False) -> Sensor | None:
    """The remote's sensor called ``name`` (:data:`SENSORS`) for ``scene``: None for "surface" (the remote's
    default, :class:`scenes.sensing.SurfaceSensor`), the scene's default camera rig for "cameras", scanning in
    the background with ``background`` (live remotes; headless sessions and replays scan in the loop's thread,
    so they repeat bit for bit).

    Raises:
        ValueError: a name not in :data:`SENSORS`.
    """
    if name == "surface":
        return None
    if name == "cameras":
        return CameraSensor.for_scene(scene, background=background)
    raise ValueError(f"unknown sensor {name!r}: one of {', '.join(SENSORS)}")


def sensor_name(sensor: Sensor | None) -> str:
    """What a recording calls the remote's ``sensor`` (its ``sensor`` metadata): "surface" for None or a
    :class:`scenes.sensing.SurfaceSensor`, "cameras" for a :class:`scenes.sensing.CameraSensor` (replayed with the
    scene's default rig, :func:`sensor_for`, whatever rig it had), else its class's name, which replay cannot
    rebuild (``twin replay --sensor`` names one it can)."""
    if sensor is None or type(sensor) is SurfaceSensor:
        return "surface"
    if type(sensor) is CameraSensor:
        return "cameras"
    return type(sensor).__name__
