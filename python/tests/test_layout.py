"""The ctypes mirrors against the Rust contract, without a running ussd.

Sizes, alignments, field names and offsets and the iceoryx2 type names come from the one layout
table of the Rust crate (shm-types/src/layout.rs); code tables, limits and service names from
the C header that cbindgen generates from the crate (shm-types/include/uss_shm_types.h, checked
against the crate by shm-types/tests/c_header.rs).
"""

import ctypes
import importlib.metadata
import re
from pathlib import Path

import pytest
from iceoryx2 import get_type_name

import uss_rt

ROOT = Path(__file__).resolve().parents[2]
LAYOUT_RS = ROOT / "shm-types" / "src" / "layout.rs"
HEADER = ROOT / "shm-types" / "include" / "uss_shm_types.h"


def rust_layouts():
    """{Rust name: (type name, size, align, [(field, offset, size)])} from layout.rs."""
    table = {}
    pattern = re.compile(
        r'TypeLayout \{\s*name: "(\w+)",\s*type_name: "(\w+)",\s*size: (\d+),\s*'
        r"align: (\d+),\s*fields: &\[(.*?)\],\s*\}",
        re.S,
    )
    for name, type_name, size, align, fields in pattern.findall(LAYOUT_RS.read_text()):
        table[name] = (
            type_name,
            int(size),
            int(align),
            [(f, int(o), int(s)) for f, o, s in re.findall(r'f\("(\w+)", (\d+), (\d+)\)', fields)],
        )
    return table


def header_text():
    return HEADER.read_text()


def screaming(camel):
    return re.sub(r"(?<!^)([A-Z])", r"_\1", camel).upper()


def test_every_payload_type_has_the_rust_size_alignment_and_field_offsets():
    rust = rust_layouts()
    assert sorted(rust) == sorted(t.__name__ for t in uss_rt.PAYLOAD_TYPES)
    for t in uss_rt.PAYLOAD_TYPES:
        type_name, size, align, fields = rust[t.__name__]
        assert (ctypes.sizeof(t), ctypes.alignment(t)) == (size, align), t.__name__
        python_fields = [
            (name, getattr(t, name).offset, getattr(t, name).size) for name, _ in t._fields_
        ]
        assert python_fields == fields, t.__name__


def test_every_payload_type_declares_the_rust_type_name():
    rust = rust_layouts()
    for t in uss_rt.PAYLOAD_TYPES:
        assert t.type_name() == rust[t.__name__][0]
        # What the binding declares when it creates a port with the type.
        assert get_type_name(t) == rust[t.__name__][0]


def test_code_tables_have_exactly_the_codes_of_the_header():
    text = header_text()
    for table in (
        uss_rt.LastFailure,
        uss_rt.RtMode,
        uss_rt.TaskCode,
        uss_rt.Storage,
        uss_rt.RequestError,
        uss_rt.Outcome,
        uss_rt.ControlState,
        uss_rt.LatchReason,
        uss_rt.Rejection,
        uss_rt.StopCommand,
        uss_rt.Monitoring,
        uss_rt.CommandError,
        uss_rt.LineState,
        uss_rt.LineFault,
        uss_rt.BusState,
        uss_rt.Direction,
    ):
        prefix = f"USS_{screaming(table.__name__)}_"
        body = re.search(r"enum Uss%s\b.*?\{(.*?)\};" % table.__name__, text, re.S).group(1)
        header = {m: int(v) for m, v in re.findall(r"%s(\w+) = (\d+)," % prefix, body)}
        assert header == {m.name: m.value for m in table}, table.__name__


def test_limits_match_the_header():
    defines = dict(re.findall(r"#define USS_(\w+) ([^\n\"]+)\n", header_text()))
    scope = {"UINT8_MAX": 0xFF, "UINT64_MAX": 0xFFFF_FFFF_FFFF_FFFF}

    def value(name):
        expression = re.sub(r"USS_(\w+)", lambda m: str(value(m.group(1))), defines[name])
        return eval(expression, {"__builtins__": {}}, scope)  # integers and '-' only

    for name in (
        "LAYOUT_VERSION",
        "MAX_PZD_WORDS",
        "EXTRA_PZD_WORDS",
        "MAX_PARAM_ITEMS",
        "MAX_SUBINDEX",
        "NO_ITEM",
        "MAX_ADDRESS",
        "MAX_BUS_NAME_LEN",
        "NEVER",
        "ALL_DRIVES",
        "OUTPUT_RELEASE",
        "REQUEST_FORCE",
        "HEARTBEAT_PERIOD_NS",
        "GONE_AFTER_NS",
        "REQUEST_SENT",
        "ANSWER_SENT",
        "CAPTURE_BYTES",
        "CAPTURE_TRUNCATED",
        "CAPTURE_TASK",
        "CAPTURE_BUFFER",
        "EXCHANGE_BUCKETS",
        "CAPTURE_MAX_SUBSCRIBERS",
    ):
        assert getattr(uss_rt, name) == value(name), name


def test_service_names_and_attribute_match_the_header():
    # C's %016llx (an unsigned long long) is Python's %016x.
    strings = {
        name: pattern.replace("%016llx", "%016x")
        for name, pattern in re.findall(r'#define USS_(\w+) "([^"]*)"', header_text())
    }
    assert uss_rt.LAYOUT_VERSION_ATTRIBUTE == strings["LAYOUT_VERSION_ATTRIBUTE"]
    generation = 0x0000_1234_ABCD_EF01
    assert uss_rt.heartbeat_service("line-1_A") == strings["SERVICE_HEARTBEAT"] % "line-1_A"
    for name, make in (
        ("SERVICE_DRIVE_OUT", uss_rt.drive_out_service),
        ("SERVICE_DRIVE_IN", uss_rt.drive_in_service),
    ):
        expected = strings[name] % ("line-1_A", generation, 7)
        assert make("line-1_A", generation, 7) == expected, name
    for name, make in (
        ("SERVICE_DIAG", uss_rt.diag_service),
        ("SERVICE_STATUS", uss_rt.status_service),
        ("SERVICE_CYCLE", uss_rt.cycle_service),
        ("SERVICE_PARAMS", uss_rt.params_service),
        ("SERVICE_COMMAND", uss_rt.command_service),
        ("SERVICE_CAPTURE", uss_rt.capture_service),
        ("SERVICE_REQUESTS", uss_rt.requests_service),
        ("SERVICE_ANSWERS", uss_rt.answers_service),
    ):
        assert make("line-1_A", generation) == strings[name] % ("line-1_A", generation), name


def test_stop_commands_carry_bit_10_and_clear_on():
    for command, stw1 in uss_rt.STOP_STW1.items():
        assert stw1 & 0x0400 and not stw1 & 0x0001, command


def test_iceoryx2_is_pinned_to_the_version_of_the_rust_workspace():
    lock = (ROOT / "Cargo.lock").read_text()
    rust = re.search(r'name = "iceoryx2"\nversion = "([^"]+)"', lock).group(1)
    requirements = (ROOT / "python" / "requirements.txt").read_text()
    pinned = re.search(r"^iceoryx2==(\S+)$", requirements, re.M)
    assert pinned.group(1) == rust
    assert importlib.metadata.version("iceoryx2") == rust


def test_float_values_decode_from_their_ieee754_bits_and_words_are_not_floats():
    assert uss_rt.ParamValue(0x4248_0000, True).as_float() == 50.0
    assert uss_rt.ParamValue(0xC120_0000, True).as_float() == -10.0
    word = uss_rt.ParamValue(0x1234, False)
    assert word == 0x1234 and not word.is_dword
    with pytest.raises(ValueError, match="0x1234"):
        word.as_float()


def test_errors_carry_their_codes_and_say_what_to_do():
    e = uss_rt.DriveError(2)
    assert e.number == 2
    assert str(e) == "the drive refused the task with error 2: limit exceeded"
    e = uss_rt.Refused(uss_rt.RequestError.WRITES_DISABLED, 0)
    assert (e.error, e.item) == (uss_rt.RequestError.WRITES_DISABLED, 0)
    assert "params_writable = false" in str(e)
    assert uss_rt.Refused(200).error == 200  # a code this module does not know stays a number
    assert isinstance(uss_rt.ParamTimeout(), TimeoutError)
    assert isinstance(uss_rt.NoAnswer("bus0", "did not answer"), TimeoutError)
    assert str(uss_rt.NotRunning("bus0")).startswith("ussd is not running on bus0: start it")
