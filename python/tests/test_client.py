"""uss_rt against a real ussd on a simulated bus.

The module starts one ``ussd --config FILE`` (``device = "sim"``, drives 1 and 2) on a bus named
after this process, so parallel runs never share a service, and stops it with SIGTERM in its
last test. ussd is built with cargo first (a no-op when it is up to date); set USSD to a binary
to use that one instead.
"""

import os
import signal
import struct
import subprocess
import time
from pathlib import Path

import pytest

import uss_rt

ROOT = Path(__file__).resolve().parents[2]
BUS = f"py{os.getpid()}"
DRIVES = (1, 2)


def binary(package: str, name: str, env: str) -> str:
    """The workspace binary ``name`` (built with cargo first), or the one ``$env`` names."""
    if env in os.environ:
        return os.environ[env]
    subprocess.run(["cargo", "build", "--quiet", "-p", package, "--bin", name], cwd=ROOT, check=True)
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    return str(target / "debug" / name)


def ussd_binary() -> str:
    return binary("uss-master", "ussd", "USSD")


def ussctl_binary() -> str:
    return binary("ussctl", "ussctl", "USSCTL")


class Ussd:
    """A ussd process running ``bus`` (BUS by default) on a simulated line with ``drives``
    (default keys) and the further ``[[bus]]`` keys ``keys``."""

    def __init__(self, tmp: Path, bus: str = BUS, drives=DRIVES, keys: str = ""):
        self.bus = bus
        self.config = tmp / f"ussd-{bus}.toml"
        # An address, or (address, further keys of its [[bus.drive]] table).
        drives = "".join(
            f"\n[[bus.drive]]\naddress = {d}\n"
            if isinstance(d, int)
            else f"\n[[bus.drive]]\naddress = {d[0]}\n{d[1]}\n"
            for d in drives
        )
        self.config.write_text(f'[[bus]]\nname = "{bus}"\ndevice = "sim"\n{keys}\n{drives}')
        self.log = tmp / f"ussd-{bus}.log"
        with self.log.open("a") as log:
            self.process = subprocess.Popen(
                [ussd_binary(), "--config", str(self.config), "--summary-every", "3600"],
                stdout=log,
                stderr=subprocess.STDOUT,
            )

    def output(self) -> str:
        return self.log.read_text()

    def wait_for_services(self, timeout: float = 20.0):
        """Returns once ussd created BUS's services."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                uss_rt.open_bus(self.bus).close()
                return
            except uss_rt.NotRunning:
                assert self.process.poll() is None, f"ussd ended early:\n{self.output()}"
                assert time.monotonic() < deadline, f"none after {timeout} s:\n{self.output()}"
                time.sleep(0.05)

    def stop(self) -> int:
        """SIGTERM, then the exit status (killed after 10 s)."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        try:
            return self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
            raise


@pytest.fixture(scope="module")
def ussd(tmp_path_factory):
    daemon = Ussd(tmp_path_factory.mktemp("ussd"))
    daemon.wait_for_services()
    yield daemon
    if daemon.process.poll() is None:
        daemon.process.kill()
        daemon.process.wait()


@pytest.fixture
def bus(ussd):
    """A bus of its own per test, closed after it: the last test needs every port gone, so
    ussd's services can go when ussd stops."""
    with uss_rt.open_bus(BUS) as bus:
        yield bus


def wait_for_input(bus, address, accept, timeout=10.0):
    """The first input image of ``address`` that ``accept`` takes."""
    deadline = time.monotonic() + timeout
    while True:
        image = uss_rt.read_input(bus, address)
        if accept(image):
            return image
        assert time.monotonic() < deadline, f"drive {address}: still {image}"
        time.sleep(0.01)


def test_bus_lists_the_polled_drives_and_runs(bus):
    assert bus.drives() == list(DRIVES)
    status = bus.status()
    assert status.version == uss_rt.LAYOUT_VERSION
    assert status.drive_count == len(DRIVES)
    assert status.running is True
    # The client's one view of the bus, as `ussctl status --json` shows it: words, not codes.
    assert (status.bus, status.line, status.line_error) == (bus.name, "up", None)
    assert status.rt_mode in ("realtime", "best effort") and status.line_down is False
    assert status.exchanges >= status.good and status.jobs_cancelled == 0
    # ... and as that JSON is read (issue 47: it had no drives and could not be subscripted).
    assert status["bus"]["bus"] == bus.name and set(status.keys()) == {"bus", "drives"}
    assert [d["address"] for d in status["drives"]] == list(DRIVES)
    assert all("online" in d and "control" in d for d in status.drives)
    deadline = time.monotonic() + 5
    while bus.status().good == 0:
        assert time.monotonic() < deadline, "no good exchange counted"
        time.sleep(0.01)


def test_input_image_is_online_in_s2_and_its_sequence_increases(bus):
    first = wait_for_input(bus, 1, lambda i: i["online"] == 1 and i["sequence"] > 0)
    later = wait_for_input(bus, 1, lambda i: i["sequence"] > first["sequence"])
    for image in (first, later):
        assert image["online"] == 1
        assert image["timestamp_ns"] > 0
        # No controller: ussd sends the safe command OFF1, which takes the drive from S1 to S2
        # (ready to switch on, OFF2 and OFF3 inactive): ZSW1 bits 0, 4 and 5 of bits 0..6.
        assert image["zsw1"] & 0x7F == 0x31, hex(image["zsw1"])
        assert image["words"][:2] == [image["zsw1"], image["hiw"]]
        assert len(image["words"]) == image["word_count"]
    assert later["timestamp_ns"] > first["timestamp_ns"]


def test_p1082_reads_as_the_float_50_hz(bus):
    value = uss_rt.read_param(bus, 1, 1082)
    assert value == 0x4248_0000
    assert value.is_dword
    assert value.as_float() == 50.0


def test_eight_threads_sharing_one_bus_take_turns_and_all_are_answered(bus):
    import threading

    answers = []

    def reader():
        answers.extend(uss_rt.read_param(bus, 1, 1082) for _ in range(10))

    threads = [threading.Thread(target=reader) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert answers == [0x4248_0000] * 80


def test_unknown_pnu_raises_drive_error_0(bus):
    with pytest.raises(uss_rt.DriveError) as e:
        uss_rt.read_param(bus, 2, 1999)
    assert e.value.number == 0
    assert "illegal parameter number" in str(e.value)


def test_drive_ussd_does_not_poll_raises_unknown_drive(bus):
    with pytest.raises(uss_rt.UnknownDrive) as e:
        uss_rt.read_input(bus, 9)
    assert e.value.known == list(DRIVES)
    with pytest.raises(uss_rt.UnknownDrive, match="drive 9 is not on"):
        uss_rt.read_param(bus, 9, 1082)


def test_a_drive_without_a_controller_is_latched_with_its_safe_command(bus):
    image = wait_for_input(bus, 1, lambda i: i["sequence"] > 0)
    assert image["control"] == uss_rt.ControlState.LATCHED
    assert image["latch_reason"] == uss_rt.LatchReason.STARTUP
    assert image["latch_command"] == uss_rt.StopCommand.OFF1
    assert image["sent_stw1"] == 0x047E
    diag = bus.diag(1)
    assert (diag["info"]["pzd_words"], diag["counters"]["latches"]) == (2, 1)
    assert (diag["info"]["reference_hz"], diag["info"]["watchdog_ms"]) == (50.0, 100)
    assert diag["info"]["family"] == "micromaster4"


def test_python_stops_a_drive_another_process_runs_and_the_stop_latches(bus):
    run = subprocess.Popen(
        [ussctl_binary(), "--bus", BUS, "run", "2", "--hz", "10", "--for", "30"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_for_input(
            bus, 2, lambda i: i["control"] == uss_rt.ControlState.LIVE and i["sent_stw1"] == 0x047F
        )
        uss_rt.stop_drive(bus, 2, uss_rt.StopCommand.OFF2)
        image = uss_rt.wait_stopped(bus, 2, uss_rt.StopCommand.OFF2)
        assert image["latch_reason"] == uss_rt.LatchReason.OVERRIDE
        assert image["sent_stw1"] == 0x047C
        assert image["latched_by_pid"] == os.getpid()
        # The controller learns of it and ends with an error; the drive stays coasted.
        _, err = run.communicate(timeout=10)
        assert run.returncode == 1, err
        assert "tripped" in err and "an operator sent OFF2" in err, err
        assert uss_rt.read_input(bus, 2)["sent_stw1"] == 0x047C
        # Every drive: OFF3 for drive 1 (it had OFF1), drive 2 keeps the stronger OFF2.
        assert uss_rt.stop_all(bus, uss_rt.StopCommand.OFF3) == list(DRIVES)
        assert uss_rt.wait_stopped(bus, 1, uss_rt.StopCommand.OFF3)["sent_stw1"] == 0x047A
        assert uss_rt.read_input(bus, 2)["sent_stw1"] == 0x047C
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()


def test_stopping_a_drive_ussd_does_not_poll_raises_unknown_drive(bus):
    with pytest.raises(uss_rt.UnknownDrive, match="drive 9 is not on"):
        uss_rt.stop_drive(bus, 9)


def test_parameters_read_in_the_manuals_notation_as_their_own_type(bus):
    assert repr(uss_rt.read(bus, 1, "P1082")) == "P1082 = 50.00 Hz"
    assert repr(uss_rt.read(bus, 1, "21")) == "r0021 = 0.00 Hz"
    assert repr(uss_rt.read(bus, 1, "r0947[0]")) == "r0947[0] = 0"
    status = uss_rt.read(bus, 1, "r0052")
    assert (status.value, status.name) == (status.raw, "CO/BO: Act. status word 1")
    assert repr(status).startswith("r0052 = 0x")
    assert uss_rt.parse_param("r0947.3") == (947, 3, "r")
    with pytest.raises(ValueError, match="write a parameter as P1082"):
        uss_rt.parse_param("Q12")
    # An array is named with its element: alone it would mean element 0, maybe not the one meant.
    with pytest.raises(ValueError, match=r"P2014: an array of 2 elements: name one, P2014\[0\]"):
        uss_rt.read(bus, 1, "P2014")
    with pytest.raises(ValueError, match=r"P2014\[0\] \(COM link, RS485\)"):
        uss_rt.write(bus, 1, "P2014", 300)
    # ussd itself refuses it, whatever the client sends.
    with pytest.raises(uss_rt.Refused, match="name the element") as refused:
        uss_rt.read_param(bus, 1, 2014)
    assert refused.value.error == uss_rt.RequestError.INDEX_REQUIRED


def test_a_batch_of_chosen_items_goes_in_one_request_with_a_result_each(bus):
    ten = struct.unpack("<I", struct.pack("<f", 10.0))[0]
    results = uss_rt.batch(bus, 2, [
        (1082, None),              # read P1082
        (1120, None, ten, True),   # write P1120 := 10.0 (a float: its bits as a double word)
        (9999, None),              # no such parameter: this item fails, the others go on
        (947, 0),                  # read r0947[0]
    ])
    assert len(results) == 4
    assert results[0].as_float() == 50.0
    assert results[1].as_float() == 10.0
    assert isinstance(results[2], uss_rt.DriveError) and results[2].number == 0
    assert results[3] == 0 and not results[3].is_dword
    with pytest.raises(ValueError, match="1 to 39 items"):
        uss_rt.batch(bus, 2, [(1082, None)] * 40)
    with pytest.raises(ValueError, match="does not fit a word"):
        uss_rt.batch(bus, 2, [(1120, None, 70000, False)])


def test_writes_convert_to_the_parameters_type_and_refuse_what_does_not_fit(bus):
    held = uss_rt.write(bus, 2, "P1120", 3)
    assert (held.value, repr(held)) == (3.0, "P1120 = 3.00 s")
    assert uss_rt.read_param(bus, 2, 1120).as_float() == 3.0
    # P0700 (the command source) takes the drive away from ussd: only deliberately.
    with pytest.raises(uss_rt.Refused, match="guarded parameter") as refused:
        uss_rt.write(bus, 2, "P0700", "0x05")
    assert refused.value.error == uss_rt.RequestError.GUARDED
    assert uss_rt.write(bus, 2, "P0700", "0x05", unsafe=True).value == 5
    with pytest.raises(ValueError, match=r"P0700: 70000 does not fit U16 \(0..=65535\)"):
        uss_rt.write(bus, 2, "P0700", 70000)
    with pytest.raises(ValueError, match="P0700: 4.5 is not a whole number"):
        uss_rt.write(bus, 2, "P0700", 4.5)
    with pytest.raises(ValueError, match="r0021: read-only"):
        uss_rt.write(bus, 2, "r0021", 5)
    with pytest.raises(uss_rt.DriveError):
        uss_rt.write(bus, 2, "P2000", 0.5)  # below the drive's limit: error 2
    # A float keeps what it is: -0.0 its sign, 3.0 its whole value, 1e-50 is refused (a float
    # parameter would hold 0), as the same text is.
    held = uss_rt.write(bus, 2, "P1120", -0.0)
    assert (held.raw, repr(held)) == (0x80000000, "P1120 = -0.00 s")
    assert uss_rt.write(bus, 2, "P0700", 5.0, unsafe=True).value == 5
    with pytest.raises(ValueError, match="does not fit float"):
        uss_rt.write(bus, 2, "P1120", 1e-50)
    uss_rt.write(bus, 2, "P1120", 3)
    assert uss_rt.drive.fault_text(72) == "USS (COM link) setpoint fault"


def test_a_copy_of_ram_to_rom_raises_the_access_level_for_it_and_puts_it_back(bus):
    # P0971 is level 3 on a MICROMASTER 4; the drive is at level 1.
    assert uss_rt.read_param(bus, 2, 3) == 1
    saved = uss_rt.save_to_rom(bus, 2)
    assert saved == {"param": "P0971", "raised": "P0003 1 -> 3 -> 1"}
    assert uss_rt.read_param(bus, 2, 3) == 1
    assert uss_rt.read_param(bus, 2, 971) == 0, "done"


def test_a_refusal_for_the_access_level_says_which_level_to_raise_to(bus):
    with pytest.raises(uss_rt.DriveError) as e:
        uss_rt.write(bus, 2, "P2014[0]", 200)
    assert e.value.number == 204
    assert "P2014 needs access level 3 (P0003 = 3)" in e.value.hint, e.value.hint
    assert e.value.hint in str(e.value)


def test_describe_says_what_the_drive_says_beside_the_catalogue(bus):
    d = uss_rt.describe(bus, 1, "P1120")
    assert (d["param"], d["family"]) == ("P1120", "micromaster4")
    assert d["drive"]["data_type"] == "Float" and d["drive"]["read_only"] is False, d
    assert d["drive"]["elements"] == 3 and d["drive"]["max"] > d["drive"]["min"], d
    c = d["catalogue"]
    assert (c["name"], c["unit"], c["data_sets"], c["agrees"]) == ("Ramp-up time", "s", 3, True), c
    assert c["change"] == "any time"
    with pytest.raises(uss_rt.DriveError):
        uss_rt.describe(bus, 1, "P0999")


def test_a_backup_holds_every_data_set_and_compares_with_the_drive_and_another(bus):
    text = uss_rt.backup(bus, 1)
    assert text.startswith("# uss-rt parameter backup (format 1)")
    assert "P1120 = [" in text and "firmware = 2.09" in text and "P0010" not in text
    same = uss_rt.diff(bus, 1, text)
    assert same["differ"] == [] and same["same"] > 40, same
    other = uss_rt.diff(bus, 1, 2)
    assert {"param": "P2011[0]", "name": "USS address", "drive": "1", "other": "2"} in other[
        "differ"
    ], other
    bad = text.replace("P0003 = 1", "P0003 = 1.5", 1)
    line = bad.splitlines().index("P0003 = 1.5") + 1
    with pytest.raises(ValueError, match=f"backup:{line}: P0003: 1.5 is not a whole number"):
        uss_rt.diff(bus, 1, bad)


def test_python_takes_control_runs_stops_and_releases_a_drive(bus):
    uss_rt.write(bus, 1, "P1120", 0.5)
    uss_rt.write(bus, 1, "P1121", 0.5)
    with uss_rt.control(bus, 1) as c:
        assert repr(c) == f"Controller(bus='{BUS}', drive=1, stw1=0x047e)"
        with pytest.raises(uss_rt.Controlled, match="drive 1 on .* is controlled by process"):
            uss_rt.control(bus, 1)
        c.rearm(time.monotonic_ns())  # ussd latched the drive at start: OFF1 re-arms it
        c.enable()
        c.wait_for(lambda i: i["zsw1"] & 0x7F == 0x31, what="S2")
        assert c.reference_hz == 50.0  # the drive's P2000, as ussd publishes it now
        c.run_hz(25)
        image = c.wait_for(lambda i: i["hiw"] == 0x2000, what="25 Hz")
        assert image["sent_stw1"] == 0x047F and image["control"] == uss_rt.ControlState.LIVE
        c.acknowledge()
        c.stop()
        c.wait_for(lambda i: i["hiw"] == 0, what="stopped")
        # An operator's stop latches the drive: the controller is told at its next call.
        uss_rt.stop_drive(bus, 1, uss_rt.StopCommand.OFF2)
        uss_rt.wait_stopped(bus, 1, uss_rt.StopCommand.OFF2)
        with pytest.raises(uss_rt.Tripped, match="drive 1 on .* latched"):
            c.run_hz(10)
        assert c.rearm(time.monotonic_ns())["control"] == uss_rt.ControlState.LIVE
    released = wait_for_input(bus, 1, lambda i: i["latch_reason"] == uss_rt.LatchReason.RELEASED)
    assert released["sent_stw1"] == 0x047E
    uss_rt.control(bus, 1).release()  # free again


def test_python_has_the_calls_rust_and_c_have(bus):
    """run_percent, set_hz, jog, reverse, wait_for_state and wait_exchange, as in Rust and C."""
    uss_rt.write(bus, 1, "P1120", 0.5)
    uss_rt.write(bus, 1, "P1121", 0.5)
    with uss_rt.control(bus, 1) as c:
        assert isinstance(c, uss_rt.Controller) and c.address == 1 and c.bus is bus
        c.rearm(time.monotonic_ns())
        c.enable()
        assert c.wait_for_state(2)["control"] == uss_rt.ControlState.LIVE
        c.run_percent(25)
        c.wait_for(lambda i: i["hiw"] == 0x1000, what="25 %")
        c.set_hz(10)  # the setpoint only: the drive keeps running
        image = c.wait_for(lambda i: abs(i["hiw"] - 0x0CCD) <= 1, what="10 Hz")
        assert image["sent_stw1"] == 0x047F
        c.reverse()
        c.wait_for(lambda i: i["sent_stw1"] == 0x0C7F, what="reversed")
        c.reverse(0)
        c.stop()
        c.wait_for_state(2)
        c.set_hz(20)  # a stopped drive stays stopped
        after = uss_rt.wait_exchange(bus, 1, count=2)
        assert after["sent_stw1"] == 0x047E and after["hiw"] == 0
        c.jog("right")
        c.wait_for(lambda i: i["sent_stw1"] == 0x057E, what="jog right")
        c.stop()
        with pytest.raises(ValueError, match="no jog direction"):
            c.jog("up")
        with pytest.raises(ValueError, match="no drive state"):
            c.wait_for_state(9)
        with pytest.raises(ValueError, match="not a finite number"):
            c.run_percent(float("nan"))
        # A setpoint beyond what the word carries (-200 % .. +199.99 % of P2000) is refused,
        # not sent as full scale: run_hz(5000) for run_hz(50) must not run the drive at 100 Hz.
        before = c.wait_for(lambda i: i["sent_stw1"] == 0x047E, what="OFF1")["sent_stw1"]
        for call in (lambda: c.run_hz(5000), lambda: c.set_hz(-1e30), lambda: c.run_percent(250)):
            with pytest.raises(ValueError, match="beyond the setpoint's range"):
                call()
        # A MICROMASTER's reference is a frequency: no speed to scale rpm by, nothing sent.
        with pytest.raises(ValueError, match="cannot be scaled: ussd knows no reference speed"):
            c.run_rpm(1500)
        after = uss_rt.wait_exchange(bus, 1, count=2)
        assert after["sent_stw1"] == before and after["hiw"] == 0
    with pytest.raises(uss_rt.WaitTimeout):
        uss_rt.wait_exchange(bus, 1, count=1000, timeout=0.05)
    faults = uss_rt.read_elements(bus, 1, "r0947")
    assert len(faults) == 8 and repr(faults[7]).startswith("r0947[7] = ")
    assert [float(v) for v in uss_rt.read_elements(bus, 1, "P1082")] == [50.0]


def test_an_operators_stop_after_the_controllers_own_stop_stays_latched(bus):
    """Issue 20, as a new user tried it: the controller's own OFF1, then an operator's coast
    from another process. The refresher must not republish the OFF1 over the coast (that
    re-armed the operator's stop), so the next ON raises Tripped and never reaches the wire."""
    with uss_rt.control(bus, 1) as drive:
        drive.rearm(time.monotonic_ns())
        for _ in range(25):  # the control loop: ON at 10 Hz for half a second
            drive.run_hz(10)
            time.sleep(0.02)
        drive.stop()
        coast = subprocess.run(
            [ussctl_binary(), "--bus", BUS, "coast", "1"], capture_output=True, text=True
        )
        # ussctl waited until the image showed the coast; then many refresher periods and
        # polls, long enough for a republished OFF1 to re-arm.
        time.sleep(0.3)
        image = uss_rt.read_input(bus, 1)
        assert image["control"] == uss_rt.ControlState.LATCHED, (image, coast.stderr)
        assert image["latch_reason"] == uss_rt.LatchReason.OVERRIDE, image
        assert coast.returncode == 0 and "OFF2 sent" in coast.stdout, (coast.stdout, coast.stderr)
        with pytest.raises(uss_rt.Tripped, match="drive 1 on .* latched"):
            drive.run_hz(10)
        time.sleep(0.1)
        assert uss_rt.read_input(bus, 1)["sent_stw1"] == 0x047C
        drive.rearm(time.monotonic_ns())  # the deliberate re-arm: OFF1, then ON may run the drive again


def test_a_python_program_that_stops_calling_trips_its_drive_and_its_next_call_says_so(bus):
    """Issue 20: the watchdog watches the program, not a thread. A program that called
    run_hz and then made no call for 0.5 s (five watchdog times) no longer keeps its drive
    live through the refresher thread; its next call is the trip."""
    with uss_rt.control(bus, 2) as drive:
        drive.rearm(time.monotonic_ns())
        drive.run_hz(10)
        drive.wait_for(lambda i: i["sent_stw1"] == 0x047F, what="ON on the wire")
        time.sleep(0.5)
        image = uss_rt.read_input(bus, 2)
        assert image["control"] == uss_rt.ControlState.LATCHED, image
        assert image["latch_reason"] == uss_rt.LatchReason.STALE, image
        assert image["sent_stw1"] == 0x047E
        with pytest.raises(uss_rt.Tripped):
            drive.run_hz(10)
        drive.rearm(time.monotonic_ns())  # the deliberate re-arm runs it again
        drive.run_hz(10)
        drive.wait_for(lambda i: i["sent_stw1"] == 0x047F, what="ON on the wire")
        drive.stop()


def test_calls_that_wait_release_the_gil(bus):
    """A thread of the program keeps running while another waits in the native module: the
    GIL is released while a call waits for the drive or for ussd's answer."""
    import threading

    counter, stop = [0], threading.Event()

    def spin():
        while not stop.is_set():
            counter[0] += 1

    spinner = threading.Thread(target=spin)
    spinner.start()
    try:
        with uss_rt.control(bus, 1) as drive:
            drive.rearm(time.monotonic_ns())
            before = counter[0]
            with pytest.raises(uss_rt.WaitTimeout):
                drive.wait_for(lambda i: False, timeout=0.3, what="never")
            during_wait = counter[0] - before
            before = counter[0]
            for _ in range(20):
                uss_rt.read_param(bus, 1, 1082)
            during_reads = counter[0] - before
    finally:
        stop.set()
        spinner.join()
    print(f"python: the other thread counted {during_wait} during a wait, {during_reads} during reads")
    assert during_wait > 10_000 and during_reads > 10_000


def test_bus_without_ussd_raises_not_running():
    with pytest.raises(uss_rt.NotRunning, match=f"ussd is not running on {BUS}x"):
        uss_rt.open_bus(f"{BUS}x")


def test_a_monitor_sees_a_killed_ussd_gone_within_a_second_and_follows_its_restart(tmp_path):
    """Its own ussd (bus BUS + "k"): SIGKILL, the monitor's image turns stale, a new ussd starts
    while the monitor still holds the old one's services, and the monitor reads it."""
    daemon = Ussd(tmp_path, BUS + "k")
    daemon.wait_for_services()
    with uss_rt.open_bus(BUS + "k") as bus:
        wait_for_input(bus, 1, lambda i: i["online"] == 1 and i["sequence"] > 0)
        drive = uss_rt.control(bus, 2)
        drive.rearm(time.monotonic_ns())
        killed = time.monotonic()
        daemon.process.kill()
        daemon.process.wait()
        stale = wait_for_input(bus, 1, lambda i: i["health"] == "gone", timeout=3.0)
        noticed = time.monotonic() - killed
        print(f"python: noticed the SIGKILL after {noticed * 1e3:.0f} ms")
        assert noticed < 2.0
        assert stale["online"] == 0
        assert isinstance(bus.health().error(), uss_rt.UssdGone)
        with pytest.raises(uss_rt.UssdGone, match="is gone"):
            uss_rt.read_param(bus, 1, 1082)
        # A controller is told too: nothing would reach the drive.
        with pytest.raises(uss_rt.UssdGone):
            drive.run_hz(10)
        restarted = Ussd(tmp_path, BUS + "k")
        try:
            back = wait_for_input(bus, 1, lambda i: i["health"] == "running" and i["online"] == 1)
            assert back["control"] == uss_rt.ControlState.LATCHED
            assert back["latch_reason"] == uss_rt.LatchReason.STARTUP
            assert uss_rt.read_param(bus, 1, 1082).as_float() == 50.0
            # The new ussd latched every drive: the controller's next call is that news.
            with pytest.raises(uss_rt.Tripped):
                drive.run_hz(10)
            drive.rearm(time.monotonic_ns())
            drive.release()
        finally:
            assert restarted.stop() == 0, restarted.output()



def test_a_write_that_reached_the_drive_but_lost_its_answer_may_be_applied(tmp_path):
    """A slow EEPROM answers "busy" past ussd's parameter timeout: the write reached the drive,
    so it is not "not done" but MaybeApplied, and a read shows the drive holds it."""
    daemon = Ussd(
        tmp_path,
        bus=f"{BUS}-eeprom",
        drives=[(1, 'sim = { eeprom-busy = 500 }')],
        keys="param_timeout_ms = 50",
    )
    try:
        daemon.wait_for_services()
        with uss_rt.open_bus(f"{BUS}-eeprom") as bus:
            wait_for_input(bus, 1, lambda i: i["online"] == 1)
            with pytest.raises(uss_rt.MaybeApplied, match="may have been applied") as lost:
                uss_rt.write(bus, 1, "P1120", 7.5, eeprom=True)
            assert lost.value.outcome == uss_rt.Outcome.TIMEOUT and lost.value.telegrams > 0
            assert isinstance(lost.value, uss_rt.ParamFailed)
            assert uss_rt.read(bus, 1, "P1120").value == 7.5
    finally:
        assert daemon.stop() == 0, daemon.output()


def test_a_stalled_program_is_told_the_stop_its_drive_got(tmp_path):
    """A program that made no call for longer than the watchdog is told Stalled, with the stop
    ussd sends a stale drive: the drive's configured safe command (OFF3 here), not OFF1."""
    daemon = Ussd(
        tmp_path,
        bus=f"{BUS}-stall",
        drives=[(1, 'safe_command = "off3"\nwatchdog_ms = 100')],
    )
    try:
        daemon.wait_for_services()
        with uss_rt.open_bus(f"{BUS}-stall") as bus:
            wait_for_input(bus, 1, lambda i: i["online"] == 1)
            drive = uss_rt.control(bus, 1)
            drive.rearm(time.monotonic_ns())
            drive.run_hz(5)
            # ussd paused (shorter than its heartbeat's 500 ms) sees no gap yet and latches
            # nothing: the program's next call, 250 ms after its last, finds the gap itself.
            daemon.process.send_signal(signal.SIGSTOP)
            try:
                time.sleep(0.25)
                with pytest.raises(uss_rt.Stalled, match="OFF3") as stalled:
                    drive.run_hz(5)
                # Rule 3: the paused ussd's diagnostics are older than their limit: stale.
                diag = bus.diag(1)
                assert (diag["stale"], diag["online"]) == (True, False), diag
            finally:
                daemon.process.send_signal(signal.SIGCONT)
            assert stalled.value.command == uss_rt.StopCommand.OFF3
            assert stalled.value.reason == uss_rt.LatchReason.STALE
            # ussd, resumed, latches the drive with the same stop.
            image = wait_for_input(bus, 1, lambda i: i["control"] == uss_rt.ControlState.LATCHED)
            assert image["latch_command"] == uss_rt.StopCommand.OFF3
            drive.release()
    finally:
        assert daemon.stop() == 0, daemon.output()


def test_each_family_reads_its_own_parameters_and_fault_buffer(tmp_path):
    """A G120 and a SIMOREG through Python: parameters typed by their family's catalogue, the
    telegram-off trip read where the family keeps faults; a generic slave has no fault buffer."""
    trip = 'p2014 = 100, unplug = "1500..2000"'
    daemon = Ussd(
        tmp_path,
        bus=f"{BUS}-families",
        drives=[
            (3, f'family = "g120"\nsim = {{ family = "g120", {trip} }}'),
            (4, f'family = "simoreg"\nsim = {{ family = "simoreg", {trip} }}'),
            (5, 'family = "generic"\nsim = { family = "generic" }'),
        ],
    )
    try:
        daemon.wait_for_services()
        with uss_rt.open_bus(f"{BUS}-families") as bus:
            # A SIMOREG's manuals write three digits (P303, r947: OI 6RX1700-0AD76).
            for address, codes, number in [(3, "r0945", 1910), (4, "r947", 11)]:
                wait_for_input(bus, address, lambda i: i["online"] == 1 and i["zsw1"] & 0x0008)
                report = uss_rt.fault_report(bus, address)
                assert report["codes"] == codes
                assert report["faults"][0]["number"] == number
            assert repr(uss_rt.read(bus, 3, "p1121")) == "p1121 = 10.00 s"
            # P303 counts 0.01 s (OI 6RX1700-0AD76): shown, read and written in seconds.
            p303 = uss_rt.read(bus, 4, "P303")
            assert repr(p303) == "P303 = 10.00 s"
            assert (p303.value, p303.raw) == (10.0, 1000)
            assert uss_rt.write(bus, 4, "P303", 5.5).raw == 550
            with pytest.raises(ValueError, match="whole number of steps of 0.01 s"):
                uss_rt.write(bus, 4, "P303", "5.555")
            with pytest.raises(ValueError, match="no fault buffer uss-rt knows"):
                uss_rt.fault_report(bus, 5)
    finally:
        daemon.stop()


def test_sigterm_stops_ussd_and_clients_are_told(ussd):
    with uss_rt.open_bus(BUS) as bus:
        assert ussd.stop() == 0, ussd.output()
        wait_for_input(bus, 1, lambda i: i["health"] == "stopped", timeout=3.0)
        assert isinstance(bus.health().error(), uss_rt.UssdStopped)
    with pytest.raises((uss_rt.NotRunning, uss_rt.UssdGone)):
        uss_rt.open_bus(BUS)



def test_quick_commissioning_and_a_factory_reset_wait_for_the_drive_and_ussd(tmp_path):
    """The guided commissioning calls from Python (issue 46): a value the drive refuses ends
    quick commissioning with the drive out of it (P0010 back to 0) and the level put back; the
    rating plate then goes in, P3900 = 3 keeps every other setting (P2000 60 Hz), the level
    raised for P0308 is put back. A factory reset brings the reference back to 50 Hz, read again
    by ussd before the call returns."""
    bus_name = f"{BUS}-commissioning"
    daemon = Ussd(tmp_path, bus=bus_name, drives=[(4, "sim = { p2000 = 60, p2014 = 500 }")])
    try:
        daemon.wait_for_services()
        with uss_rt.open_bus(bus_name) as bus:
            wait_for_input(bus, 4, lambda i: i["online"] == 1)
            # The end of quick commissioning is guarded: asked as unsafe, or nothing is written;
            # a guarded motor value (telegram monitoring off) is refused even then.
            with pytest.raises(uss_rt.Refused, match="deliberately as unsafe"):
                uss_rt.quick_commission(bus, 4, [("P0304", "400")])
            assert uss_rt.read_param(bus, 4, 304) != 400
            with pytest.raises(uss_rt.Refused, match="guarded parameter"):
                uss_rt.quick_commission(bus, 4, [("P2014[0]", "0")], unsafe=True)
            assert uss_rt.read(bus, 4, "P2014[0]").value != 0
            assert uss_rt.read_param(bus, 4, 10) == 0, "out of quick commissioning"
            with pytest.raises(uss_rt.DriveError):
                uss_rt.quick_commission(
                    bus, 4, [("P0308", "0.8"), ("P2000", "0.5")], unsafe=True
                )
            assert uss_rt.read_param(bus, 4, 10) == 0, "out of quick commissioning"
            assert uss_rt.read_param(bus, 4, 3) == 1, "the level put back"
            plate = {"P0304": 400, "P0305": 1.9, "P0308": 0.82, "P0310": 50, "P0311": 1395}
            done = uss_rt.quick_commission(bus, 4, plate, unsafe=True)
            assert done["writes"][:3] == ["P0010 := 1", "P0304 := 400 V", "P0305 := 1.90 A"]
            assert done["writes"][-1] == "P3900 := 3"
            assert done["raised"] == "P0003 1 -> 2 -> 1"
            assert done["reference_hz"] == 60.0
            assert uss_rt.read(bus, 4, "P0311").value == 1395
            assert [uss_rt.read_param(bus, 4, p) for p in (10, 3900, 3)] == [0, 0, 1]
            text = uss_rt.backup(bus, 4)
            with pytest.raises(uss_rt.Refused, match="deliberately as unsafe"):
                uss_rt.factory_reset(bus, 4)
            reset = uss_rt.factory_reset(bus, 4, unsafe=True)
            assert reset["writes"] == ["P0010 := 30", "P0970 := 1"]
            assert reset["reference_hz"] == 50.0
            assert uss_rt.read(bus, 4, "P2000").value == 50.0
            # The backup restored onto the reset drive: the rating plate (quick commissioning
            # entered around it and left) and P2000 back; the drive equals its backup.
            plan = uss_rt.restore(bus, 4, text, dry_run=True)
            assert plan["written"] == 0 and "P0304" in [l["param"] for l in plan["lines"]]
            with pytest.raises(uss_rt.Refused, match="deliberately as unsafe"):
                uss_rt.restore(bus, 4, text.replace("P0700 = [5, 5, 5]", "P0700 = [2, 5, 5]"))
            done = uss_rt.restore(bus, 4, text)
            # P0304, P0305, P0308, P0311 (P0310 is the factory 50 Hz), P2000 and the telegram
            # monitoring P2014[0] the reset had switched off.
            assert done["complete"] and done["refused"] == 0 and done["written"] == 6, done
            assert uss_rt.read(bus, 4, "P2014[0]").value == 500
            assert uss_rt.diff(bus, 4, text)["differ"] == []
            assert uss_rt.read(bus, 4, "P2000").value == 60.0
            assert [uss_rt.read_param(bus, 4, p) for p in (10, 3)] == [0, 1]
    finally:
        assert daemon.stop() == 0, daemon.output()


def test_a_backup_asked_to_discover_saves_what_the_drive_describes_beyond_the_catalogue(
    tmp_path,
):
    """A drive's list is longer than uss-rt's catalogue (issue 46, item 2): ``discover`` asks
    the drive for every number of a range the catalogue does not list, and the settable ones
    it has are saved under ``[described]``, typed as it describes them; restored and compared
    like the catalogue's."""
    bus_name = f"{BUS}-described"
    daemon = Ussd(tmp_path, bus=bus_name, drives=[(4, 'sim = { extra = "701-702" }')])
    try:
        daemon.wait_for_services()
        with uss_rt.open_bus(bus_name) as bus:
            wait_for_input(bus, 4, lambda i: i["online"] == 1)
            uss_rt.write(bus, 4, "P0701", 9)
            assert "[described." not in uss_rt.backup(bus, 4)
            with pytest.raises(ValueError, match="discover"):
                uss_rt.backup(bus, 4, discover=(710, 700))
            text = uss_rt.backup(bus, 4, discover=(700, 710))
            assert "[described.P0701]" in text and "[described.P0702]" in text, text
            assert "[described.P0700]" not in text, "the catalogue's P0700 is under [param]"
            uss_rt.write(bus, 4, "P0701", 3)
            differ = uss_rt.diff(bus, 4, text)["differ"]
            assert [d["param"] for d in differ] == ["P0701"], differ
            done = uss_rt.restore(bus, 4, text)
            assert done["complete"] and done["written"] == 1, done
            assert uss_rt.diff(bus, 4, text)["differ"] == []
            assert uss_rt.read(bus, 4, "P0701").value == 9
    finally:
        assert daemon.stop() == 0, daemon.output()
