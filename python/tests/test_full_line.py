"""A Python controller on a full line at the drives' factory baud rate (issue 21): 31 simulated
drives at 9600 baud, where ussd polls each drive only every 1.3 s. Every wait of the client is
the drive's own (its image's ``stale_after_ns``), not a fixed second: on main before this, the
re-arm failed with "ussd did not update the inputs ... for 1s"."""

import os
import subprocess
import time

import pytest

import uss_rt
from test_client import Ussd, ussctl_binary

BUS = f"pyfull{os.getpid()}"
DRIVES = tuple(range(1, 32))


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    daemon = Ussd(tmp_path_factory.mktemp("full"), bus=BUS, drives=DRIVES, keys="baud = 9600")
    daemon.wait_for_services()
    with uss_rt.open_bus(BUS) as bus:
        # Every drive answered once: a full cycle went by.
        for address in DRIVES:
            image = None
            for _ in range(2000):
                image = uss_rt.read_input(bus, address)
                if image["online"] == 1 and image["sequence"] > 0:
                    break
                __import__("time").sleep(0.01)
            assert image["online"] == 1, f"drive {address}: {image}\n{daemon.output()}"
        # ... and ussd read the reference frequency of the drives run here (its own reads take
        # a few of the line's 1.3 s cycles; until then a setpoint in Hz is refused).
        for address in (21, 22):
            for _ in range(3000):
                if bus.diag(address)["info"]["reference_hz"] > 0:
                    break
                time.sleep(0.01)
            assert bus.diag(address)["info"]["reference_hz"] > 0, f"drive {address}"
        yield daemon, bus
    daemon.stop()


def test_the_image_says_how_often_the_drive_is_polled(line):
    _, bus = line
    image = uss_rt.read_input(bus, 20)
    # 31 exchanges of at least 42.6 ms of wire time each.
    assert image["period_ns"] >= 1_250_000_000, image
    assert image["stale_after_ns"] >= 2 * image["period_ns"], image
    assert image["health"] == "running"


def test_a_python_controller_runs_and_stops_drive_21(line):
    _, bus = line
    with uss_rt.control(bus, 21) as drive:
        assert drive.handshake() >= 2.5
        drive.rearm(time.monotonic_ns())
        drive.run_hz(10)
        image = drive.wait_for(lambda i: i["sent_stw1"] == 0x047F and i["zsw1"] & 0x4 != 0,
                               what="S4")
        assert image["control"] == uss_rt.ControlState.LIVE
        drive.stop()
        drive.wait_for(lambda i: i["sent_stw1"] == 0x047E, what="OFF1 sent")
    image = uss_rt.read_input(bus, 21)
    assert image["latch_reason"] == uss_rt.LatchReason.RELEASED


def test_an_operator_stop_of_a_drive_python_runs_is_confirmed_and_trips_the_controller(line):
    _, bus = line
    with uss_rt.control(bus, 22) as drive:
        drive.rearm(time.monotonic_ns())
        drive.run_hz(10)
        drive.wait_for(lambda i: i["sent_stw1"] == 0x047F, what="ON sent")
        stop = subprocess.run([ussctl_binary(), "--bus", BUS, "stop", "22"],
                              capture_output=True, text=True, timeout=60)
        assert stop.returncode == 0, stop.stdout + stop.stderr
        image = uss_rt.wait_stopped(bus, 22, uss_rt.StopCommand.OFF1)
        assert image["sent_stw1"] == 0x047E
        with pytest.raises(uss_rt.Tripped):
            drive.run_hz(10)
