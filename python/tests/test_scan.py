"""``uss_rt.scan`` against ``uss-sim --pty`` (issue 46, item 5): the library's scan, the one
``ussctl scan`` renders, from Python: every drive of the line with its layout, family and
firmware; a line that cannot be used is a ``DeviceError`` (an ``OSError`` too)."""

import subprocess

import pytest

import uss_rt
from test_client import binary


@pytest.fixture
def line():
    sim = subprocess.Popen(
        [
            binary("uss-drive-sim", "uss-sim", "USS_SIM"),
            "--pty",
            "--baud",
            "19200",
            "--drive",
            "3:pkw=4,pzd=2",
            "--drive",
            "5:pkw=127,pzd=6,family=g120",
            "--drive",
            "6:pkw=4,pzd=6,family=generic",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    first = sim.stdout.readline().strip()
    assert first.startswith("PTY "), first
    yield first[4:]
    sim.terminate()
    sim.wait()


def test_a_scan_finds_each_drive_with_its_layout_family_and_firmware(line):
    scanned = uss_rt.scan(line, bauds=[19200], addresses=range(2, 8))
    drives = {d["address"]: d for d in scanned["drives"]}
    assert sorted(drives) == [3, 5, 6], scanned
    assert drives[3] == {
        "baud": 19200,
        "address": 3,
        "pkw": 4,
        "pzd": 2,
        "zsw1": 0xBB31,
        "firmware": 2.09,
        "family": "micromaster4",
        "unsure": None,
    }
    assert (drives[5]["pkw"], drives[5]["pzd"], drives[5]["family"], drives[5]["firmware"]) == (
        127,
        6,
        "g120",
        4.7,
    )
    # A generic slave answers P0003 with a double word: a 4-word channel.
    assert (drives[6]["pkw"], drives[6]["pzd"], drives[6]["family"], drives[6]["unsure"]) == (
        4,
        6,
        None,
        None,
    )
    assert scanned["seconds"] > 0


def test_a_line_that_cannot_be_used_is_a_device_error(tmp_path):
    with pytest.raises(uss_rt.DeviceError) as e:
        uss_rt.scan(str(tmp_path / "ttyUSB9"), bauds=[19200], addresses=[1])
    assert isinstance(e.value, OSError)
    assert "No such file or directory" in str(e.value)
    plain = tmp_path / "plain"
    plain.write_text("")
    with pytest.raises(uss_rt.DeviceError, match="is not a serial device"):
        uss_rt.scan(str(plain), bauds=[19200], addresses=[1])
    with pytest.raises(ValueError):
        uss_rt.scan(str(plain), bauds=[19200], addresses=[40])
