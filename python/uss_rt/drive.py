"""Parameters the way a drives engineer writes them, and exclusive control of a drive.

- :func:`read` / :func:`write`: a parameter in the manuals' notation (``P1082``, ``p1082``,
  ``r0021``, ``1082``, ``P0947[3]``, ``r0947.3``) as its own type and unit (``P1082 = 50.00 Hz``);
  a write converts the value to the parameter's type and refuses what does not fit before the
  bus. What a parameter is comes from the Rust catalogue (``uss-catalogue``), or from the
  drive's own description for a parameter it does not know.
- :func:`control`: the drive's one controller, on the client rules every language shares
  (``uss_shm_types::session`` in Rust): ``rearm``, ``enable``, ``run_hz``, ``stop``,
  ``coast``, ``quick_stop``, ``acknowledge``, ``keepalive``, ``release``.
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
    """A parameter value in its own type: ``value`` (float or int), ``raw`` (the word or
    double word), ``data_type``, ``unit`` and ``name``. ``repr`` is ``P1082 = 50.00 Hz``."""

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


class Controller:
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
    """

    def __init__(self, bus, address: int):
        _u._check_address(address)
        self.bus, self.address = bus, address
        self._c = _native.control(bus._open(), address)
        self.words_count = self._c.words_count

    def inputs(self) -> dict:
        """The drive's input image (:func:`uss_rt.read_input`)."""
        return _u._image(self._c.inputs())

    def check(self) -> dict:
        """The drive's input image; raises :class:`Tripped` for a latch this controller has
        not acknowledged (a read: it does not refresh the watchdog)."""
        return _u._image(self._c.check())

    def keepalive(self):
        """The control loop's refresh: the current words again."""
        self._c.keepalive()

    def enable(self):
        """OFF1 (STW1 0x047E): S1 -> S2; stops a running drive. It re-arms nothing: a latched
        drive needs :meth:`rearm`."""
        self._c.enable()

    def rearm(self) -> dict:
        """Acknowledges the latch (a trip, an operator's stop, ussd's start) and re-arms: OFF1
        naming it, then waits until ussd passes this controller's words again."""
        return _u._image(self._c.rearm())

    @property
    def reference_hz(self) -> float:
        """The reference frequency P2000 ussd publishes now (0x4000 = 100 %): the drive's own
        value once ussd has read it, until then the configuration's ``reference_hz``."""
        return self._c.reference_hz

    def run_hz(self, hz: float):
        """ON (STW1 0x047F) with a setpoint in Hz, scaled by the reference frequency P2000 that
        ussd publishes (:attr:`reference_hz`)."""
        self._c.run_hz(float(hz))

    def stop(self):
        """OFF1: ramp down, then S2."""
        self._c.stop()

    def coast(self):
        """OFF2: pulses off at once, the motor coasts."""
        self._c.coast()

    def quick_stop(self):
        """OFF3: the quick-stop ramp."""
        self._c.quick_stop()

    def reverse(self, reverse: bool = True):
        """Sets or clears the reverse bit (STW1 bit 11)."""
        self._c.reverse(bool(reverse))

    def acknowledge(self, timeout=None):
        """Acknowledges a fault: a rising edge of STW1 bit 7 until the drive received it (at
        most ``timeout`` s; None: the drive's handshake time, :meth:`handshake`), then OFF1."""
        self._c.acknowledge(timeout)

    def handshake(self) -> float:
        """How long a call waits for what the drive's next poll brings, s: ussd's freshness
        limit for the drive (its turn in the circulating list and the poll with its retries),
        at least 1 s. A full line at 9600 baud polls each drive only every 1.3 s."""
        return self._c.handshake()

    def set_words(self, words):
        """Sends the PZD ``words`` as they are (STW1 first, bit 10 set, the drive's length)."""
        self._c.set_words(list(words))

    def wait_for(self, predicate, timeout=None, what: str = "the drive") -> dict:
        """Waits until ``predicate(image)`` holds, refreshing the watchdog meanwhile (this
        program waits inside its own call); raises :class:`Tripped` as soon as the drive
        latches, :class:`WaitTimeout` after ``timeout`` s (None: 3 s for the drive and its
        :meth:`handshake` time for the bus to carry the command and the answer)."""
        if timeout is None:
            timeout = 3.0 + self.handshake()
        return _u._image(self._c.wait_for(lambda raw: predicate(_u._image(raw)), timeout, what))

    def release(self):
        """Hands the drive back cleanly: ussd sends its safe command and shows it "released",
        which is not a watchdog trip."""
        self._c.release()

    def __enter__(self):
        return self

    def __exit__(self, *_):
        self.release()

    def __repr__(self):
        return repr(self._c)


def control(bus, address: int) -> Controller:
    """Takes exclusive control of drive ``address``; raises :class:`Controlled` while another
    controller holds it."""
    return Controller(bus, address)
