"""The Python face of the native module against the Rust contract, without a running ussd.

The enums are made from the native module's own code tables (the Rust crate's); these tests
hold them to the C header that cbindgen generates from the same crate
(shm-types/include/uss_shm_types.h, checked against the crate by shm-types/tests/c_header.rs),
and check the exception classes the native module raises.
"""

import re
from pathlib import Path

import pytest

import uss_rt

ROOT = Path(__file__).resolve().parents[2]
HEADER = ROOT / "shm-types" / "include" / "uss_shm_types.h"


def header_text():
    return HEADER.read_text()


def screaming(camel):
    return re.sub(r"(?<!^)([A-Z])", r"_\1", camel).upper()


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


def test_the_native_module_speaks_the_headers_layout_version():
    version = re.search(r"#define USS_LAYOUT_VERSION (\d+)", header_text()).group(1)
    assert uss_rt.LAYOUT_VERSION == int(version)


def test_stop_commands_carry_bit_10_and_clear_on():
    for command, stw1 in uss_rt.STOP_STW1.items():
        assert stw1 & 0x0400 and not stw1 & 0x0001, command


def test_float_values_decode_from_their_ieee754_bits_and_words_are_not_floats():
    assert uss_rt.ParamValue(0x4248_0000, True).as_float() == 50.0
    assert uss_rt.ParamValue(0xC120_0000, True).as_float() == -10.0
    word = uss_rt.ParamValue(0x1234, False)
    assert word == 0x1234 and not word.is_dword
    with pytest.raises(ValueError, match="0x1234"):
        word.as_float()


def test_errors_are_the_code_tables_classes_with_the_rust_message_and_their_details():
    # The classes are generated from the Rust client's code table (clients/src/kinds.rs).
    for name in uss_rt._errors.__all__:
        assert issubclass(getattr(uss_rt, name), uss_rt.UssError), name
    assert issubclass(uss_rt.ParamTimeout, TimeoutError)
    assert issubclass(uss_rt.NoAnswer, TimeoutError)
    assert issubclass(uss_rt.WaitTimeout, TimeoutError)
    assert issubclass(uss_rt.NotArmed, uss_rt.Tripped)
    assert issubclass(uss_rt.Stalled, uss_rt.Tripped)
    assert issubclass(uss_rt.MaybeApplied, uss_rt.ParamFailed)
    # The native module raises each with the Rust client's message and what it is about.
    e = uss_rt.Refused("ussd refused the request", error=uss_rt.RequestError.BUSY, item=None)
    assert (str(e), e.error, e.item) == ("ussd refused the request", uss_rt.RequestError.BUSY, None)


def test_parameters_are_parsed_in_the_manuals_notation_by_the_rust_code():
    assert uss_rt.parse_param("P1082") == (1082, None, "P")
    assert uss_rt.parse_param("p1082") == (1082, None, "p")
    assert uss_rt.parse_param("r0947.3") == (947, 3, "r")
    assert uss_rt.parse_param("P0947[3]") == (947, 3, "P")
    assert uss_rt.parse_param("21") == (21, None, "P")
    with pytest.raises(ValueError, match="write a parameter as P1082"):
        uss_rt.parse_param("Q12")
    assert uss_rt.fault_text(72) == "USS (COM link) setpoint fault"
    # A fault number is read in its drive family's catalogue: F0004 of a MICROMASTER is not a
    # SIMOREG's, whose texts this catalogue does not have.
    assert uss_rt.fault_text(4, family="micromaster4") == "Inverter overtemperature"
    assert uss_rt.fault_text(4, family="g110") == "Inverter overtemperature"
    assert uss_rt.fault_text(4, family="simoreg") is None
    assert uss_rt.fault_text(4, family="g120") is None
    assert uss_rt.fault_text(4, family="generic") is None
    assert uss_rt.warning_text(501) == uss_rt.warning_text(501, "micromaster4") is not None
    assert uss_rt.warning_text(501, "g120") is None
    with pytest.raises(ValueError, match="is not a drive family: give one of micromaster4, g110"):
        uss_rt.fault_text(4, family="mm4")
