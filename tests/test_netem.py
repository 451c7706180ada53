"""The emulated link: its statistics against its parameters, its determinism, its checks, and a headless run.

Statistical tolerances are 5 standard errors of the estimate (a false failure about once in 3.5 million
runs, and the seeds are fixed anyway), so a test fails on a wrong model, not on sampling noise.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from estimation.errors import TwinError
from sync.clock import SimClock
from sync.inprocess import InProcessBus
from sync.netem import Conditions, ConditionsError, GilbertElliott, LinkModel, Network

N = 100_000
Z = 5.0  # standard errors of tolerance


def _model(seed: int = 0, **conditions: object) -> LinkModel:
    return LinkModel(Conditions(**conditions), np.random.default_rng(seed))  # type: ignore[arg-type]


def _send(model: LinkModel, n: int = N, *, every: float = 1e-3, size: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Send ``n`` packets ``every`` seconds; (send times, arrival times with NaN for the lost)."""
    sent = np.arange(n) * every
    arrived = np.array([np.nan if (a := model.send(t, size)) is None else a for t in sent])
    return sent, arrived


@pytest.mark.parametrize("distribution, delay, jitter", [("normal", 0.05, 0.01), ("normal", 0.03, 0.01),
                                                         ("exponential", 0.05, 0.02)])
def test_mean_delay_and_jitter_are_what_was_asked(distribution, delay, jitter):
    # reorder=True: each packet keeps its own draw (FIFO would hold some back and raise the mean).
    sent, arrived = _send(_model(delay=delay, jitter=jitter, distribution=distribution, reorder=True))
    d = arrived - sent
    # SE of a mean: sigma / sqrt(n); of a standard deviation: about sigma / sqrt(2 n) (x2 for the
    # exponential's heavier tail, whose kurtosis is 9 rather than 3).
    assert abs(d.mean() - delay) < Z * jitter / math.sqrt(N)
    assert abs(d.std() - jitter) < Z * 2 * jitter / math.sqrt(2 * N)
    # Never below zero: the normal at 3 sigma is redrawn, the exponential is floored at delay - jitter.
    assert d.min() >= (0.0 if distribution == "normal" else delay - jitter)
    if distribution == "exponential":  # p99 of delay - jitter + Exp(jitter) is delay + (ln 100 - 1) jitter
        assert np.percentile(d, 99) == pytest.approx(delay + (math.log(100) - 1) * jitter, rel=0.02)


def test_without_jitter_every_packet_takes_the_delay():
    sent, arrived = _send(_model(delay=0.05), 1000)
    assert np.all(arrived - sent == pytest.approx(0.05, abs=1e-12))


def test_independent_loss_rate():
    model = _model(loss=0.1)
    _, arrived = _send(model)
    lost = np.isnan(arrived).mean()
    assert abs(lost - 0.1) < Z * math.sqrt(0.1 * 0.9 / N)
    assert model.stats.lost == np.isnan(arrived).sum() and model.stats.delivered + model.stats.lost == N


def _bursts(lost: np.ndarray) -> np.ndarray:
    """Lengths of the runs of consecutive losses."""
    edges = np.diff(np.concatenate([[0], lost.astype(int), [0]]))
    return np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)


def test_gilbert_elliott_stationary_loss_and_mean_burst_length():
    n, p, r = 400_000, 0.01, 0.2
    burst = GilbertElliott(p=p, r=r)
    assert burst.stationary_loss == pytest.approx(p / (p + r))
    _, arrived = _send(_model(burst=burst), n)
    lost = np.isnan(arrived)
    # Losses are correlated (lag-1 correlation rho = 1 - p - r), which inflates the binomial variance
    # by (1 + rho) / (1 - rho).
    rho, pi = 1 - p - r, p / (p + r)
    assert abs(lost.mean() - pi) < Z * math.sqrt(pi * (1 - pi) / n * (1 + rho) / (1 - rho))
    lengths = _bursts(lost)  # geometric, mean 1 / r, standard deviation sqrt(1 - r) / r
    assert abs(lengths.mean() - 1 / r) < Z * math.sqrt(1 - r) / r / math.sqrt(len(lengths))
    # Bursty: far longer runs than independent loss at the same rate would give (mean 1 / (1 - pi) ~ 1.05).
    independent = _bursts(np.random.default_rng(1).random(n) < pi)
    assert lengths.mean() > 4 * independent.mean()


def test_gilbert_elliott_with_lossy_states_matches_its_formula():
    burst = GilbertElliott(p=0.05, r=0.25, loss_bad=0.6, loss_good=0.02)
    expected = (0.25 * 0.02 + 0.05 * 0.6) / 0.3
    assert burst.stationary_loss == pytest.approx(expected)
    _, arrived = _send(_model(burst=burst), 200_000)
    assert np.isnan(arrived).mean() == pytest.approx(expected, rel=0.05)


def test_a_saturated_cap_delivers_exactly_the_cap():
    rate, size = 1e6, 1000  # 8 ms a packet, offered every 4 ms: twice the cap
    model = _model(rate_bps=rate)
    _, arrived = _send(model, 2000, every=0.004, size=size)
    throughput = (len(arrived) - 1) * size * 8 / (arrived[-1] - arrived[0])
    assert throughput == pytest.approx(rate, rel=1e-9)
    assert model.stats.queue_delay > 0


def test_a_full_queue_drops_at_the_tail_and_bounds_the_queueing_delay():
    rate, size, limit = 1e6, 1000, 10_000
    model = _model(rate_bps=rate, queue_bytes=limit)
    sent, arrived = _send(model, 2000, every=0.004, size=size)
    ok = ~np.isnan(arrived)
    assert model.stats.dropped == (~ok).sum() > 0 and model.stats.lost == 0
    assert (~ok).mean() == pytest.approx(0.5, abs=0.01)  # half of twice the cap cannot go
    assert np.diff(arrived[ok]) == pytest.approx(8 * size / rate)  # the transmitter never idles
    assert (arrived - sent)[ok].max() <= limit * 8 / rate + 1e-12  # waiting for at most a full queue


def test_under_the_cap_a_packet_waits_only_for_its_own_serialisation():
    model = _model(rate_bps=1e6, delay=0.01)
    sent, arrived = _send(model, 500, every=0.01, size=1000)
    assert arrived - sent == pytest.approx(0.01 + 0.008)
    assert model.stats.queue_delay == 0


def test_fifo_never_reorders_and_reordering_does_when_asked():
    _, fifo = _send(_model(delay=0.05, jitter=0.01), 5000)
    assert np.all(np.diff(fifo) >= 0)
    _, free = _send(_model(delay=0.05, jitter=0.01, reorder=True), 5000)
    assert np.any(np.diff(free) < 0)


def test_the_same_seed_gives_the_same_arrivals():
    c = dict(delay=0.02, jitter=0.005, loss=0.05, rate_bps=2e6)
    first, second, other = (_send(_model(s, **c), 5000)[1] for s in (3, 3, 4))
    assert first.tobytes() == second.tobytes()
    assert first.tobytes() != other.tobytes()
    up, down = Network(uplink=Conditions(**c), downlink=Conditions(**c), seed=7).models()
    assert _send(up, 100)[1].tobytes() != _send(down, 100)[1].tobytes()  # each direction its own draws


@pytest.mark.parametrize("make, match", [
    (lambda: Conditions(delay=-0.01), r"^delay must be finite and in \[0, 3600\], got -0.01$"),
    # arrival times of infinity: an OverflowError in the in-process transport's nanosecond clock
    (lambda: Conditions(delay=1e308), r"^delay must be finite and in \[0, 3600\], got 1e\+308$"),
    (lambda: Conditions(delay=math.nan), r"^delay must be finite"),
    (lambda: Conditions(delay=0.01, jitter=math.inf), r"^jitter must be finite"),
    (lambda: Conditions(loss=1.5), r"^loss must be finite and in \[0, 1\], got 1.5$"),
    (lambda: Conditions(loss=-0.1), r"^loss must be finite and in \[0, 1\]"),
    (lambda: Conditions(delay=0.03, jitter=0.02), r"^jitter 0.02 s is more than normal jitter allows .* 0.01 s\)"),
    (lambda: Conditions(delay=0.05, jitter=0.06, distribution="exponential"), r"more than exponential jitter"),
    (lambda: Conditions(delay=0.05, jitter=0.01, distribution="pareto"), r"^distribution must be one of normal"),
    (lambda: Conditions(rate_bps=0), r"^rate_bps must be finite and in \[1, inf\]"),
    (lambda: Conditions(rate_bps=1e-300), r"^rate_bps must be finite and in \[1, inf\]"),
    (lambda: Network(seed=-5), r"^seed must be an integer in \[0, "),
    (lambda: Network(seed=1.5), r"^seed must be an integer"),
    (lambda: Conditions(rate_bps=-1e6), r"^rate_bps must be"),
    (lambda: Conditions(rate_bps=math.inf), r"^rate_bps must be"),
    (lambda: Conditions(rate_bps=1e6, queue_bytes=0), r"^queue_bytes must be"),
    (lambda: Conditions(queue_bytes=1000), r"^queue_bytes needs rate_bps"),
    (lambda: Conditions(loss=0.1, burst=GilbertElliott(0.1, 0.5)), r"^loss and burst both given"),
    (lambda: GilbertElliott(p=1.2, r=0.5), r"^burst.p must be"),
    (lambda: GilbertElliott(p=0.1, r=0.0), r"^burst.r must be finite and in \(0, 1\]"),
    (lambda: GilbertElliott(p=0.1, r=0.5, loss_bad=2), r"^burst.loss_bad must be"),
    (lambda: Conditions(delay="soon"), r"^delay must be a number, got 'soon'$"),  # type: ignore[arg-type]
])
def test_impossible_conditions_are_one_line_value_errors(make, match):
    with pytest.raises(ConditionsError, match=match) as err:
        make()
    assert isinstance(err.value, ValueError) and isinstance(err.value, TwinError)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(("delay", "jitter"), [(0.3, 0.1), (0.03, 0.01), (0.15, 0.05)])
def test_jitter_of_exactly_a_third_of_the_delay_is_allowed(delay, jitter):
    # 0.3 / 3 is 0.09999999999999999 in floats: the limit has a relative slack.
    assert Conditions(delay=delay, jitter=jitter).jitter == jitter
    with pytest.raises(ConditionsError, match="more than normal jitter"):
        Conditions(delay=delay, jitter=jitter * 1.001)


def test_jitter_at_a_third_of_the_delay_on_the_command_lines(tmp_path, capsys):
    from cli.main import main

    garbage = tmp_path / "garbage.mcap"  # the conditions are checked before the recording is read
    garbage.write_bytes(b"not a recording")
    assert main(["replay", str(garbage), "--delay", "300", "--jitter", "100"]) == 2
    assert "not a readable tactile-twin recording" in capsys.readouterr().err
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("mine\n")  # the folder is checked after every condition
    assert main(["experiment", str(Path(__file__).parent / "data" / "small.toml"), "--delays", "300",
                 "--jitter", "100", "--out", str(theirs)]) == 2
    assert "not a folder this command wrote" in capsys.readouterr().err


def test_the_bus_delivers_over_a_link_when_due_and_at_once_without_one():
    clock = SimClock()
    link = _model(delay=0.05)
    bus = InProcessBus(clock, {("a", "b"): link})
    a, b = bus.transport("a"), bus.transport("b")
    got_a: list[str] = []
    got_b: list[tuple[float, str]] = []
    a.subscribe("m", lambda k, _d: got_a.append(k))
    b.subscribe("k/**", lambda k, _d: got_b.append((clock.now(), k)))
    b.subscribe("k/1", lambda k, _d: got_b.append((clock.now(), k + "!")))  # same side: one packet, two calls
    a.put("k/1", b"x" * 10)
    clock.advance(0.01)
    a.put("k/2", b"y")
    b.put("m", b"z")  # b -> a has no link: at once
    assert got_a == ["m"] and got_b == [] and bus.in_flight == 2
    clock.advance(0.0399)
    assert bus.deliver_due() == 0
    clock.advance_to(0.05)
    assert bus.deliver_due() == 1 and got_b == [(0.05, "k/1"), (0.05, "k/1!")]
    clock.advance_to(0.06)
    assert bus.deliver_due() == 1 and got_b[-1] == (0.06, "k/2")
    assert (link.stats.sent, link.stats.delivered, link.stats.bytes_delivered) == (2, 2, 11)
    b.queryable("q", lambda _s: [("q", b"now")])
    assert a.get("q", timeout=1.0) == [("q", b"now")]  # queries are not delayed


def test_the_bus_keeps_each_direction_in_order_and_forgets_a_closed_receiver():
    clock = SimClock()
    bus = InProcessBus(clock, {("a", "b"): _model(delay=0.02, jitter=0.005)})
    a, b = bus.transport("a"), bus.transport("b")
    got: list[int] = []
    b.subscribe("k", lambda _k, d: got.append(int(d)))
    for i in range(500):
        a.put("k", str(i).encode())
        clock.advance(0.001)
        bus.deliver_due()
    clock.advance(1.0)
    bus.deliver_due()
    assert got == list(range(500))
    a.put("k", b"500")
    b.close()
    clock.advance(1.0)
    assert bus.deliver_due() == 0 and got[-1] == 499


def test_links_need_a_clock():
    with pytest.raises(ValueError, match="needs a clock"):
        InProcessBus(links={("a", "b"): _model()})


SMALL = Path(__file__).parent / "data" / "small.toml"


def test_a_headless_twin_sees_poses_50_ms_after_the_remote_sent_them(tmp_path_factory):
    from scenes.headless import Headless
    from scenes.scenefile import load_scene
    from twin.trajectory import push_trajectory

    cache = tmp_path_factory.getbasetemp() / "coacd"
    network = Network(uplink=Conditions(delay=0.05), downlink=Conditions(delay=0.05), seed=1)
    with Headless(load_scene(SMALL), cache_dir=cache, network=network) as session:
        start, t0 = session.local.twin.data.mocap_pos[0].copy(), session.local.twin.time
        push = push_trajectory(start, start + np.array([0.6, 0.0, -0.03]), 2.0, start_time=t0)
        session.run(2.0, trajectory=push)
        latency = np.array(session.local.report.pose_latency)
        dt = session.dt
        assert session.local.report.pose_updates > 50
        # Stamped on the simulated clock when sent, measured when handled: the link's 50 ms, rounded up
        # to a whole physics step.
        assert np.all(latency >= 0.05 - 1e-9) and np.all(latency <= math.ceil(0.05 / dt - 1e-9) * dt + 1e-9)
        assert session.downlink is not None and session.uplink is not None
        assert session.downlink.stats.delivered > 50 and session.downlink.stats.lost == 0
        assert session.uplink.stats.sent > 0  # the operator's commands went the other way
        assert session.downlink.stats.mean_delay == pytest.approx(0.05)
