"""Parameters the way a drives engineer writes them, and exclusive control of a drive.

- :func:`read` / :func:`write`: a parameter in the manuals' notation (``P1082``, ``p1082``,
  ``r0021``, ``1082``, ``P0947[3]``, ``r0947.3``) as its own type and unit (``P1082 = 50.00 Hz``);
  a write converts the value to the parameter's type and refuses what does not fit before the
  bus. What a parameter is comes from the Rust catalogue (``uss-catalogue``), or from the
  drive's own description for a parameter it does not know.
- :func:`control`: the drive's one controller, on the client rules every language shares
  (``uss_control::session`` in Rust): ``rearm``, ``enable``, ``run_hz``, ``run_percent``,
  ``run_rpm``, ``set_hz``, ``jog``, ``stop``, ``coast``, ``quick_stop``, ``acknowledge``,
  ``keepalive``, ``wait_for_state``, ``release``.
"""

import uss_rt as _u
from uss_rt import _native


def parse_param(text: str):
    """``(pnu, index, prefix)`` of a parameter as the manuals write it: ``P1082``, ``p1082``,
    ``r0021``, ``1082``, ``P0947[3]``, ``r0947.3``. Raises :class:`ValueError` otherwise."""
    return _native.parse_param(text)


def fault_text(number: int, family: str = "micromaster4"):
    """The text of fault ``number`` (F0072 -> 72) for a drive of ``family`` (``micromaster4``,
    ``g110``, ``g120``, ``simoreg``, ``generic``: a drive's ``diag(address)["info"]["family"]``),
    or None where that family's catalogue has none: a number means different faults in
    different families. Raises :class:`ValueError` for another family name."""
    return _native.fault_text(number, family)


def warning_text(number: int, family: str = "micromaster4"):
    """The text of warning ``number`` (A0501 -> 501) for a drive of ``family``, as
    :func:`fault_text`."""
    return _native.warning_text(number, family)


class Value:
    """A parameter value in its own type and unit: ``value`` (float or int; a fixed-point
    parameter's as a float of its unit, SIMOREG P303's raw 1000 is 10.0 s), ``raw`` (the word
    or double word), ``data_type``, ``unit`` and ``name``. ``repr`` is ``P1082 = 50.00 Hz``."""

    def __init__(self, fields: dict):
        self.param = fields["param"]
        self.raw = fields["raw"]
        self.is_dword = fields["is_dword"]
        self.data_type = fields["data_type"]
        self.value = fields["value"]
        self.unit = fields["unit"]
        self.name = fields["name"]
        self._shown = fields["shown"]
        self._text = fields["text"]

    def shown(self) -> str:
        """``50.00 Hz``, ``5``, ``0xFB31`` (a status or control word)."""
        return self._shown

    def __float__(self):
        return float(self.value)

    def __int__(self):
        return int(self.value)

    def __eq__(self, other):
        if isinstance(other, Value):
            return (self.param, self.raw) == (other.param, other.raw)
        return self.value == other

    def __hash__(self):
        return hash((self.param, self.raw))

    def __repr__(self):
        return self._text


def _value_text(value) -> str:
    """A number or text as the text the parameter's type is parsed from."""
    if isinstance(value, bool):
        raise ValueError(f"{value} is not a number")
    if isinstance(value, float):
        # The shortest text that reads back as this float: -0.0 keeps its sign, 3.0 is taken
        # by an integer parameter as 3 (the parsing is uss_client's, as for every front-end).
        return repr(value)
    return str(value)


def read(bus, address: int, param: str, timeout: float = 7.5) -> Value:
    """Reads ``param`` (the manuals' notation) of drive ``address`` as its own type."""
    _u._check_address(address)
    return Value(_native.read(bus._open(), address, param, timeout))


def read_elements(bus, address: int, param: str, timeout: float = 7.5) -> list:
    """Every element of an array parameter named without one (``r0947``: all 8), or the one
    element or plain parameter named, each as its own type."""
    _u._check_address(address)
    return [Value(v) for v in _native.read_elements(bus._open(), address, param, timeout)]


def write(bus, address: int, param: str, value, eeprom: bool = False, force: bool = False,
          timeout: float = 7.5, unsafe: bool = False) -> Value:
    """Writes ``value`` (a number or text) to ``param`` of drive ``address``, converted to the
    parameter's type (45 is 45.0 for a float parameter); what does not fit, or a read-only
    parameter, raises :class:`ValueError` before the bus. Returns the value the drive now holds.
    ``force`` writes while another process controls the drive (a deliberate act); ``unsafe``
    writes even a parameter that takes the drive away from ussd (command or setpoint source,
    COM link, telegram monitoring off, factory reset): ussd logs it, the value is verified."""
    _u._check_address(address)
    fields = _native.write(bus._open(), address, param, _value_text(value), eeprom, force,
                           timeout, unsafe)
    return Value(fields)


class Controller(_native.Controller):
    """The one controller of a drive: its words go to the drive while it is live; ussd
    latches it (its safe command) when this controller stops calling within the drive's
    watchdog time, sends a bad sample, or an operator stops it, and every call then raises
    :class:`Tripped` until :meth:`rearm`.

    **The watchdog watches this program.** Every command refreshes it; call one (or
    :meth:`keepalive`) at least once per watchdog time (``watchdog_ms``, 100 ms by default). A
    thread fills shorter gaps, but only while the program's own calls keep coming: a program
    that blocks or pauses for longer trips its drive, and its next call raises
    :class:`Stalled` or :class:`Tripped`: a trip, not a fresh start. Leaving a ``with`` block
    (or :meth:`release`) hands the drive back cleanly ("released", not a trip).

    The commands (``run_hz``, ``run_percent``, ``run_rpm``, ``set_hz``, ``jog``, ``stop``, ``coast``,
    ``quick_stop``, ``reverse``, ``acknowledge``, ``set_words``, ``keepalive``, ``enable``,
    ``release``) are the native class's, documented there; the images are dicts with enums.
    """

    def __new__(cls, bus, address: int):
        _u._check_address(address)
        return super().__new__(cls, bus._open(), address)

    def __init__(self, bus, address: int):
        self.bus = bus

    def inputs(self) -> dict:
        """The drive's input image (:func:`uss_rt.read_input`)."""
        return _u._image(super().inputs())

    def check(self) -> dict:
        """The drive's input image; raises :class:`Tripped` for a latch this controller has
        not acknowledged (a read: it does not refresh the watchdog)."""
        return _u._image(super().check())

    def rearm(self, asked_ns: int) -> dict:
        """Acknowledges the latch (a trip, an operator's stop, ussd's start) and re-arms: OFF1
        naming it, then waits until ussd passes this controller's words again.

        ``asked_ns`` is when the deliberate act that asked for the re-arm happened, on
        ``CLOCK_MONOTONIC`` (``time.monotonic_ns()`` on Linux): :func:`uss_rt.process_start_ns`
        for a script that re-arms once it is set up, ``time.monotonic_ns()`` taken when an
        operator pressed the button. A latch that began after it (an operator's stop while the
        script was starting) is not re-armed: :class:`Tripped`, and the stop stays."""
        return _u._image(super().rearm(asked_ns))

    def wait_for(self, predicate, timeout=None, what: str = "the drive") -> dict:
        """Waits until ``predicate(image)`` holds, refreshing the watchdog meanwhile (this
        program waits inside its own call); raises :class:`Tripped` as soon as the drive
        latches, :class:`WaitTimeout` after ``timeout`` s (None: 3 s for the drive and its
        :meth:`handshake` time for the bus to carry the command and the answer)."""
        timeout = self._wait_time(timeout)
        return _u._image(super().wait_for(lambda raw: predicate(_u._image(raw)), timeout, what))

    def wait_for_state(self, state: int, timeout=None) -> dict:
        """Waits until the drive shows state ``state`` (1..4 for S1..S4, 6 fault), as
        :meth:`wait_for` does."""
        return _u._image(super().wait_for_state(state, self._wait_time(timeout)))

    def _wait_time(self, timeout) -> float:
        """A wait's ``timeout``; None: 3 s for the drive and its handshake time for the bus."""
        return 3.0 + self.handshake() if timeout is None else timeout


def control(bus, address: int) -> Controller:
    """Takes exclusive control of drive ``address``; raises :class:`Controlled` while another
    controller holds it."""
    return Controller(bus, address)
