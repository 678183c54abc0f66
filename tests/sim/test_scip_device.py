"""The simulated Hokuyos' state commands, command by command (no real time): SCIP 2.2's
``%ST``/``%SL``/``RT``/``RB`` on the UST-10LX, the SCIP 2.0 models' refusal of them, and
the echo of a streamed scan."""

from __future__ import annotations

import pytest

from acq.drivers.scip_codec import Reply, parse_reply
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice


def ask(dev: ScipDevice, command: str, now: float) -> Reply:
    return parse_reply(dev.handle(command.encode() + b"\n", now))


def state(dev: ScipDevice, now: float) -> str:
    reply = ask(dev, "%ST", now)
    assert reply.status == "00"
    (line,) = reply.lines
    return str(line, "ascii")


def test_ust_reports_its_state_through_a_session() -> None:
    dev = ScipDevice(MODELS["ust-10lx"])
    t = 100.0
    assert state(dev, t) == "000"  # standby
    assert ask(dev, "BM", t).status == "00"
    assert state(dev, t) == "003"  # single scan: laser on
    assert ask(dev, "MD0000108000000", t).status == "00"
    assert state(dev, t) == "004"  # multi scan: streaming
    assert ask(dev, "QT", t).status == "00"
    assert state(dev, t) == "000"
    assert ask(dev, "TM0", t).status == "00"
    assert state(dev, t) == "002"  # time adjustment: %ST, VV and II still answer
    assert parse_reply(dev.handle(b"VV\n", t), info=True).status == "00"
    assert ask(dev, "QT", t).status == "0E"  # what urg_library takes for the TM state
    assert ask(dev, "TM2", t).status == "00"
    assert ask(dev, "%SL", t).status == "00"
    assert state(dev, t) == "005"  # sleep
    assert ask(dev, "BM", t).status == "00"  # wakes it
    assert state(dev, t) == "003"
    assert dev.clock.ticks(t + 0.2) > 1000
    assert ask(dev, "RT", t).status == "00"  # partial reset: standby, laser off, timer 0
    assert state(dev, t) == "000"
    assert dev.clock.ticks(t + 0.2) == 200
    assert ask(dev, "RB", t).status == "01"  # reboot: asked twice within a second
    assert ask(dev, "RB", t + 0.5).status == "00"
    assert dev.clock.reboots == 1
    assert state(dev, t + 0.5) == "000"


@pytest.mark.parametrize("name", ["urg-04lx", "utm-30lx"])
@pytest.mark.parametrize("command", ["%ST", "%SL", "RT", "RB"])
def test_scip20_models_do_not_know_the_ust_state_commands(name: str, command: str) -> None:
    dev = ScipDevice(MODELS[name])
    reply = ask(dev, command, 100.0)
    assert (reply.echo, reply.status, reply.lines) == (command.encode(), "0E", ())
    assert dev.clock.reboots == 0


@pytest.mark.parametrize("command", ["MD0000108000000", "ME0000108001000", "MD0100020002103"])
def test_a_streamed_scan_echoes_the_request_as_sent(command: str) -> None:
    dev = ScipDevice(MODELS["ust-10lx"])
    assert ask(dev, command, 100.0).status == "00"
    telegrams = dev.poll(100.2).split(b"\n\n")
    first = telegrams[0].split(b"\n")
    count = int(command[-2:])
    assert first[0] == (command[:-2] + f"{max(count - 1, 0):02d}").encode()
    assert first[1] == b"99b"


@pytest.mark.parametrize("name", ["urg-04lx", "utm-30lx", "ust-10lx"])
def test_rs_sets_the_internal_timer_back_to_zero(name: str) -> None:
    dev = ScipDevice(MODELS[name])
    assert dev.clock.ticks(100.0) == 100_000
    assert ask(dev, "RS", 100.0).status == "00"
    assert dev.clock.ticks(100.5) == 500
