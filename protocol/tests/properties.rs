//! Property tests of the codec: telegrams round-trip byte-exact (USS.md section 3), the framer
//! finds every telegram that follows a start pause whatever else is on the line (section 4), and
//! the PKW and PZD codecs round-trip every value they can carry (sections 6 and 7).
#![allow(clippy::unwrap_used)] // strategies and helpers only build values the codec must accept

use core::time::Duration;
use proptest::collection::vec;
use proptest::prelude::*;
use proptest::sample::Index;
use uss_protocol::telegram::{MAX_TELEGRAM_BYTES, STX};
use uss_protocol::{
    Address, Adr, Baud, EncodeError, ErrorNumber, FrameError, Framer, FramerConfig, Layout,
    LineError, ParamRef, ParamReply, ParamTask, PkwError, PkwMode, Pnu, PzdCount, ReplyKind,
    Setpoint, Storage, Subindex, Telegram, Timing, Value, encode, encode_raw,
};

// Telegrams (USS.md section 3).

/// Any ADR byte, built from its parts, with the byte USS.md section 3 says it is.
fn adr() -> impl Strategy<Value = (Adr, u8)> {
    (0u8..=31, any::<bool>(), any::<bool>(), any::<bool>()).prop_map(
        |(address, broadcast, mirror, special)| {
            let adr = Adr {
                address: Address::new(address).unwrap(),
                broadcast,
                mirror,
                special,
            };
            let byte =
                address | u8::from(broadcast) << 5 | u8::from(mirror) << 6 | u8::from(special) << 7;
            (adr, byte)
        },
    )
}

/// A PKW channel of 0, 3 or 4 words.
fn pkw_words() -> impl Strategy<Value = Vec<u16>> {
    prop_oneof![Just(0usize), Just(3), Just(4)].prop_flat_map(|n| vec(any::<u16>(), n))
}

/// The bytes a telegram with this header and net data must be on the wire: STX, LGE = n + 2, ADR,
/// the net bytes, and the XOR of all of them, STX included.
fn wire_bytes(adr: u8, net: &[u8]) -> Vec<u8> {
    let mut bytes = vec![0x02, (net.len() + 2) as u8, adr];
    bytes.extend_from_slice(net);
    bytes.push(bytes.iter().fold(0, |acc, b| acc ^ b));
    bytes
}

/// A valid telegram of any ADR and net bytes, mostly short to keep the cases quick.
fn telegram() -> impl Strategy<Value = Vec<u8>> {
    (
        any::<u8>(),
        prop_oneof![4 => vec(any::<u8>(), 0..=24), 1 => vec(any::<u8>(), 0..=252)],
    )
        .prop_map(|(adr, net)| {
            let mut buf = [0u8; MAX_TELEGRAM_BYTES];
            let n = encode_raw(&mut buf, Adr::from_byte(adr), &net).unwrap();
            buf[..n].to_vec()
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn encoded_telegram_is_byte_exact_and_parses_back_to_its_words(
        (adr, adr_byte) in adr(),
        pkw in pkw_words(),
        pzd in vec(any::<u16>(), 0..=16),
    ) {
        let mut buf = [0u8; MAX_TELEGRAM_BYTES];
        let n = encode(&mut buf, adr, &pkw, &pzd).unwrap();
        let net: Vec<u8> = pkw.iter().chain(&pzd).flat_map(|w| w.to_be_bytes()).collect();
        prop_assert_eq!(&buf[..n], &wire_bytes(adr_byte, &net)[..]);

        let t = Telegram::parse(&buf[..n]).unwrap();
        prop_assert_eq!(t.adr(), adr);
        prop_assert_eq!(usize::from(t.lge()), net.len() + 2);
        let modes: &[PkwMode] = match pkw.len() {
            0 => &[PkwMode::None],
            3 => &[PkwMode::Three, PkwMode::Variable],
            _ => &[PkwMode::Four, PkwMode::Variable],
        };
        for &mode in modes {
            let words = t.words(Layout::new(mode, PzdCount::new(pzd.len()).unwrap())).unwrap();
            prop_assert_eq!(words.pkw(), &pkw[..]);
            prop_assert_eq!(words.pzd(), &pzd[..]);
        }
    }

    #[test]
    fn raw_telegram_of_up_to_252_net_bytes_round_trips(
        (adr, adr_byte) in adr(),
        net in vec(any::<u8>(), 0..=252),
    ) {
        let mut buf = [0u8; MAX_TELEGRAM_BYTES];
        let n = encode_raw(&mut buf, adr, &net).unwrap();
        prop_assert_eq!(&buf[..n], &wire_bytes(adr_byte, &net)[..]);
        let t = Telegram::parse(&buf[..n]).unwrap();
        prop_assert_eq!(t.adr(), adr);
        prop_assert_eq!(t.net(), &net[..]);
    }

    #[test]
    fn raw_telegram_over_252_net_bytes_is_refused(len in 253usize..=1024) {
        let mut buf = [0u8; 2048];
        prop_assert_eq!(
            encode_raw(&mut buf, Adr::from_byte(0), &vec![0x55; len]),
            Err(EncodeError::TooLong(len))
        );
    }
}

// The framer (USS.md section 4).

/// A standard baud rate or any other the crate accepts.
fn timing() -> impl Strategy<Value = Timing> {
    prop_oneof![
        prop::sample::select(Baud::STANDARD.to_vec()),
        300u32..=12_000_000,
    ]
    .prop_map(|baud| Timing::new(Baud::new(baud).unwrap()))
}

/// Line silence of at least a start pause: 2 tz plus up to 8 tz more, given in thousandths of tz.
fn pause_after(timing: Timing, extra_millis_of_tz: u32) -> Duration {
    timing.start_pause() + timing.char_time() * extra_millis_of_tz / 1000
}

/// The extra silence for [`pause_after`]: often none, to hold the framer to exactly a start pause.
fn extra() -> impl Strategy<Value = u32> {
    prop_oneof![Just(0u32), 0u32..=8000]
}

fn line_error() -> impl Strategy<Value = LineError> {
    prop_oneof![
        Just(LineError::Parity),
        Just(LineError::Framing),
        Just(LineError::Overrun),
    ]
}

type Event = Result<Vec<u8>, FrameError>;

/// A receive line: hands a framer bytes with the times a UART delivers them (when the stop bit
/// has arrived) and records what the framer yields.
struct Line {
    framer: Framer,
    tz: Duration,
    /// Arrival of the last character sent, or a later time the line was looked at.
    now: Duration,
    events: Vec<Event>,
}

impl Line {
    fn new(timing: Timing) -> Self {
        Self {
            framer: Framer::new(FramerConfig::strict(timing)),
            tz: timing.char_time(),
            now: Duration::ZERO,
            events: Vec::new(),
        }
    }

    fn push(&mut self, byte: u8, at: Duration) {
        if let Some(event) = self.framer.push(byte, at) {
            self.events.push(event.map(|t| t.as_bytes().to_vec()));
        }
    }

    /// Sends `bytes` back to back after `silence`, handed over in chunks of `chunk` bytes stamped
    /// with the arrival of each chunk's last byte, as a USB adapter delivers them (1 = byte by
    /// byte). Returns the arrival of the first byte.
    fn send_chunked(&mut self, bytes: &[u8], silence: Duration, chunk: usize) -> Duration {
        let start = self.now + silence;
        let mut sent = 0u32;
        for piece in bytes.chunks(chunk) {
            sent += piece.len() as u32;
            let at = start + self.tz * sent;
            for &b in piece {
                self.push(b, at);
            }
        }
        self.now = start + self.tz * sent;
        start + self.tz
    }

    fn send(&mut self, bytes: &[u8], silence: Duration) -> Duration {
        self.send_chunked(bytes, silence, 1)
    }

    /// The UART reports the next character, after `silence`, as broken.
    fn line_error(&mut self, error: LineError, silence: Duration) {
        self.now += silence + self.tz;
        let event = self.framer.push_line_error(error, self.now);
        self.events.push(Err(event));
    }

    /// The receiver's residual timer fires at `at`.
    fn poll(&mut self, at: Duration) {
        self.now = self.now.max(at);
        if let Some(error) = self.framer.poll(at) {
            self.events.push(Err(error));
        }
    }
}

/// Something on the line that is not a telegram, with the one error the framer must report for it.
#[derive(Debug, Clone)]
enum Burst {
    /// Bytes that do not start with STX.
    Noise(Vec<u8>),
    /// STX, an LGE outside 2..=254, then anything.
    BadLge(Vec<u8>),
    /// A telegram whose BCC is wrong.
    BadBcc(Vec<u8>),
    /// The start of a telegram that never ends; the receiver's residual timer fires.
    Truncated(Vec<u8>),
    /// A telegram one character of which the UART reports as broken.
    BrokenChar {
        telegram: Vec<u8>,
        at: usize,
        error: LineError,
    },
}

fn burst() -> impl Strategy<Value = Burst> {
    prop_oneof![
        (
            any::<u8>().prop_filter("noise does not start with STX", |b| *b != STX),
            vec(any::<u8>(), 0..=32)
        )
            .prop_map(|(first, rest)| Burst::Noise([vec![first], rest].concat())),
        (
            prop_oneof![Just(0u8), Just(1), Just(255)],
            vec(any::<u8>(), 0..=16)
        )
            .prop_map(|(lge, rest)| Burst::BadLge([vec![STX, lge], rest].concat())),
        (telegram(), 1u8..=255).prop_map(|(mut t, flip)| {
            *t.last_mut().unwrap() ^= flip;
            Burst::BadBcc(t)
        }),
        (telegram(), any::<Index>()).prop_map(|(mut t, keep)| {
            t.truncate(1 + keep.index(t.len() - 1));
            Burst::Truncated(t)
        }),
        (telegram(), any::<Index>(), line_error()).prop_map(|(telegram, at, error)| {
            let at = at.index(telegram.len());
            Burst::BrokenChar {
                telegram,
                at,
                error,
            }
        }),
    ]
}

/// What goes on the line, each item after a silence of at least a start pause.
#[derive(Debug, Clone)]
enum Item {
    /// A telegram handed over in chunks; with `echo` it is heard a second time at once, without
    /// a start pause (a two-wire adapter that echoes).
    Telegram {
        bytes: Vec<u8>,
        chunk: usize,
        echo: bool,
    },
    Burst(Burst),
}

fn item() -> impl Strategy<Value = Item> {
    prop_oneof![
        (telegram(), 1usize..=300, prop::bool::weighted(0.2))
            .prop_map(|(bytes, chunk, echo)| Item::Telegram { bytes, chunk, echo }),
        burst().prop_map(Item::Burst),
    ]
}

/// Sends `item` after `silence` and returns the events the framer must yield for it.
fn send_item(line: &mut Line, timing: Timing, item: &Item, silence: Duration) -> Vec<Event> {
    match item {
        Item::Telegram { bytes, chunk, echo } => {
            line.send_chunked(bytes, silence, *chunk);
            if !echo {
                return vec![Ok(bytes.clone())];
            }
            line.send(bytes, Duration::ZERO);
            vec![Ok(bytes.clone()), Err(FrameError::StartPauseNotObserved)]
        }
        Item::Burst(Burst::Noise(bytes)) => {
            line.send(bytes, silence);
            vec![Err(FrameError::MissingStx(bytes[0]))]
        }
        Item::Burst(Burst::BadLge(bytes)) => {
            line.send(bytes, silence);
            vec![Err(FrameError::BadLge(bytes[1]))]
        }
        Item::Burst(Burst::BadBcc(bytes)) => {
            line.send(bytes, silence);
            let (body, last) = bytes.split_at(bytes.len() - 1);
            let expected = body.iter().fold(0, |acc, b| acc ^ b);
            vec![Err(FrameError::Bcc {
                expected,
                actual: last[0],
            })]
        }
        Item::Burst(Burst::Truncated(bytes)) => {
            let stx_at = line.send(bytes, silence);
            // Until LGE arrives the timer is armed for the longest telegram (USS.md section 4).
            let net = bytes.get(1).map_or(252, |&lge| usize::from(lge) - 2);
            let allowed = timing.max_residual(net);
            let late = Duration::from_nanos(1);
            line.poll(stx_at + allowed + late);
            vec![Err(FrameError::ResidualTimeExceeded {
                allowed,
                elapsed: allowed + late,
            })]
        }
        Item::Burst(Burst::BrokenChar {
            telegram,
            at,
            error,
        }) => {
            line.send(&telegram[..*at], silence);
            let silence = if *at == 0 { silence } else { Duration::ZERO };
            line.line_error(*error, silence);
            line.send(&telegram[*at + 1..], Duration::ZERO);
            vec![Err(FrameError::Line(*error))]
        }
    }
}

/// One step of an arbitrary conversation with the framer.
#[derive(Debug, Clone)]
enum Op {
    Push(u8),
    Poll,
    LineError(LineError),
    LineBusy,
    Reset,
}

/// Instants anywhere, out of order, including the extremes.
fn instant() -> impl Strategy<Value = Duration> {
    prop_oneof![
        8 => (0u64..=200_000_000).prop_map(Duration::from_nanos),
        1 => any::<u64>().prop_map(Duration::from_nanos),
        1 => Just(Duration::ZERO),
        1 => Just(Duration::MAX),
    ]
}

/// Gaps between consecutive instants: mostly below a character time at the fast rates, sometimes
/// long enough for any start pause or residual time.
fn gap() -> impl Strategy<Value = Duration> {
    prop_oneof![
        6 => (0u64..=200_000).prop_map(Duration::from_nanos),
        1 => (0u64..=500_000_000).prop_map(Duration::from_nanos),
    ]
}

/// Steps with their instants, either monotonic (from gaps) or arbitrary. Bytes come as random
/// runs and as whole valid telegrams, so that the framer has something to find.
fn ops() -> impl Strategy<Value = Vec<(Op, Duration)>> {
    let bytes = prop_oneof![vec(any::<u8>(), 1..=16), telegram()];
    let step = prop_oneof![
        8 => bytes.prop_map(|b| b.into_iter().map(Op::Push).collect::<Vec<_>>()),
        1 => Just(vec![Op::Poll]),
        1 => line_error().prop_map(|e| vec![Op::LineError(e)]),
        1 => Just(vec![Op::LineBusy]),
        1 => Just(vec![Op::Reset]),
    ];
    let steps = vec(step, 0..=24).prop_map(|s| s.concat());
    prop_oneof![
        steps.clone().prop_flat_map(|ops| {
            let n = ops.len();
            (Just(ops), vec(gap(), n)).prop_map(|(ops, gaps)| {
                let mut at = Duration::ZERO;
                let times = gaps.into_iter().map(|g| {
                    at = at.saturating_add(g);
                    at
                });
                ops.into_iter().zip(times).collect()
            })
        }),
        steps.prop_flat_map(|ops| {
            let n = ops.len();
            (Just(ops), vec(instant(), n))
                .prop_map(|(ops, times)| ops.into_iter().zip(times).collect())
        }),
    ]
}

/// Splits a telegram's words for every layout: right or wrong, none may panic.
fn split_every_way(t: Telegram<'_>) {
    for pkw in [
        PkwMode::None,
        PkwMode::Three,
        PkwMode::Four,
        PkwMode::Variable,
    ] {
        for pzd in 0..=16 {
            let _ = t.words(Layout::new(pkw, PzdCount::new(pzd).unwrap()));
        }
    }
}

fn framer_config() -> impl Strategy<Value = FramerConfig> {
    (
        timing(),
        any::<bool>(),
        0u64..=20_000_000,
        0u64..=20_000_000,
    )
        .prop_map(
            |(timing, require_start_pause, slack, pause_slack)| FramerConfig {
                timing,
                require_start_pause,
                residual_slack: Duration::from_nanos(slack),
                start_pause_slack: Duration::from_nanos(pause_slack),
            },
        )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn telegrams_separated_by_start_pauses_are_all_delivered_in_order(
        timing in timing(),
        sends in vec((telegram(), extra(), 1usize..=300), 1..=8),
    ) {
        let mut line = Line::new(timing);
        for (bytes, extra, chunk) in &sends {
            line.send_chunked(bytes, pause_after(timing, *extra), *chunk);
        }
        let expected: Vec<Event> = sends.iter().map(|(bytes, ..)| Ok(bytes.clone())).collect();
        prop_assert_eq!(line.events, expected);
    }

    #[test]
    fn every_telegram_after_a_pause_survives_garbage_and_each_burst_is_one_error(
        timing in timing(),
        items in vec((item(), extra()), 1..=12),
    ) {
        let mut line = Line::new(timing);
        let mut expected = Vec::new();
        for (item, extra) in &items {
            expected.extend(send_item(&mut line, timing, item, pause_after(timing, *extra)));
        }
        prop_assert_eq!(line.events, expected);
    }

    #[test]
    fn telegram_arriving_after_a_stalled_ones_deadline_is_received(
        timing in timing(),
        stalled in telegram(),
        keep in any::<Index>(),
        next in telegram(),
        late_nanos in 1u64..=10_000_000,
    ) {
        let mut line = Line::new(timing);
        let stalled = &stalled[..=keep.index(stalled.len() - 1)];
        let stx_at = line.send(stalled, timing.start_pause());
        let net = stalled.get(1).map_or(252, |&lge| usize::from(lge) - 2);
        let allowed = timing.max_residual(net);
        // The next STX arrives after the deadline and after a start pause, with no poll before.
        let to_deadline = (stx_at + allowed).saturating_sub(line.now);
        let silence = to_deadline.max(timing.start_pause()) + Duration::from_nanos(late_nanos);
        let next_at = line.send(&next, silence);
        let elapsed = next_at.saturating_sub(stx_at);
        prop_assert!(elapsed > allowed);
        prop_assert_eq!(
            line.events,
            vec![Err(FrameError::ResidualTimeExceeded { allowed, elapsed }), Ok(next)]
        );
    }

    #[test]
    fn framer_never_panics_and_yields_only_valid_telegrams(
        config in framer_config(),
        ops in ops(),
    ) {
        let mut framer = Framer::new(config);
        for (op, at) in ops {
            match op {
                Op::Push(byte) => {
                    if let Some(Ok(t)) = framer.push(byte, at) {
                        prop_assert_eq!(Telegram::parse(t.as_bytes()), Ok(t));
                        split_every_way(t);
                    }
                }
                Op::Poll => {
                    let deadline = framer.deadline();
                    let error = framer.poll(at);
                    prop_assert_eq!(error.is_some(), deadline.is_some_and(|d| at > d));
                }
                Op::LineError(e) => {
                    prop_assert_eq!(framer.push_line_error(e, at), FrameError::Line(e));
                    prop_assert!(!framer.is_receiving());
                }
                Op::LineBusy => framer.line_busy_until(at),
                Op::Reset => framer.reset(),
            }
        }
    }

    #[test]
    fn single_bit_error_is_never_delivered_as_a_telegram(
        timing in timing(),
        telegram in telegram(),
        at in any::<Index>(),
        bit in 0u8..8,
    ) {
        let mut corrupted = telegram.clone();
        let at = at.index(corrupted.len());
        corrupted[at] ^= 1 << bit;
        prop_assert!(Telegram::parse(&corrupted).is_err());

        let mut line = Line::new(timing);
        line.send(&telegram, timing.start_pause());
        line.send(&corrupted, timing.start_pause());
        // Long after: a telegram left waiting for bytes that never come is dropped by its timer.
        line.poll(line.now + timing.max_residual(252) + timing.start_pause());
        prop_assert_eq!(&line.events[0], &Ok(telegram));
        let rest = &line.events[1..];
        prop_assert!(rest.iter().any(Result::is_err), "{:?}", rest);
        // Only a flipped LGE can make a shorter prefix that happens to check; never the whole.
        for delivered in rest.iter().filter_map(|e| e.as_ref().ok()) {
            prop_assert_eq!(at, 1);
            prop_assert!(delivered.len() < corrupted.len());
            prop_assert_eq!(&delivered[..], &corrupted[..delivered.len()]);
        }
    }
}

// PKW (USS.md section 6).

fn pnu() -> impl Strategy<Value = Pnu> {
    any::<u16>().prop_map(Pnu::from_u16)
}

fn subindex() -> impl Strategy<Value = Subindex> {
    (0u8..=254).prop_map(|i| Subindex::new(i).unwrap())
}

fn word() -> BoxedStrategy<Value> {
    any::<u16>().prop_map(Value::Word).boxed()
}

fn dword() -> BoxedStrategy<Value> {
    any::<u32>().prop_map(Value::Dword).boxed()
}

fn value() -> BoxedStrategy<Value> {
    prop_oneof![word(), dword()].boxed()
}

fn storage() -> impl Strategy<Value = Storage> {
    prop_oneof![Just(Storage::Ram), Just(Storage::RamAndEeprom)]
}

/// Every task variant; change tasks carry values from `value`.
fn task(value: BoxedStrategy<Value>) -> impl Strategy<Value = ParamTask> {
    prop_oneof![
        Just(ParamTask::None),
        pnu().prop_map(|pnu| ParamTask::Read { pnu }),
        (pnu(), value.clone(), storage()).prop_map(|(pnu, value, storage)| ParamTask::Write {
            pnu,
            value,
            storage
        }),
        (pnu(), subindex()).prop_map(|(pnu, element)| ParamTask::ReadDescription { pnu, element }),
        (pnu(), subindex()).prop_map(|(pnu, index)| ParamTask::ReadArray { pnu, index }),
        (pnu(), subindex(), value, storage()).prop_map(|(pnu, index, value, storage)| {
            ParamTask::WriteArray {
                pnu,
                index,
                value,
                storage,
            }
        }),
        pnu().prop_map(|pnu| ParamTask::ReadArrayLen { pnu }),
    ]
}

/// A change task carrying a double word.
fn dword_task() -> impl Strategy<Value = ParamTask> {
    task(dword()).prop_filter("carries a double word", ParamTask::is_write)
}

/// Error numbers as a reply carries them: named ones often, any other too.
fn param_error() -> impl Strategy<Value = ErrorNumber> {
    prop_oneof![0u16..=210, any::<u16>()].prop_map(ErrorNumber::from_number)
}

fn reply_kind() -> impl Strategy<Value = ReplyKind> {
    prop_oneof![
        Just(ReplyKind::NotYet),
        any::<u16>().prop_map(ReplyKind::Word),
        any::<u32>().prop_map(ReplyKind::Dword),
        value().prop_map(ReplyKind::Description),
        any::<u16>().prop_map(ReplyKind::ArrayWord),
        any::<u32>().prop_map(ReplyKind::ArrayDword),
        any::<u16>().prop_map(ReplyKind::ElementCount),
        param_error().prop_map(ReplyKind::Error),
        Just(ReplyKind::NoChangeRights),
        (9u8..=12, value()).prop_map(|(id, value)| ReplyKind::ChangeReport { id, value }),
        (13u8..=15, value()).prop_map(|(id, value)| ReplyKind::Other { id, value }),
    ]
}

fn reply() -> impl Strategy<Value = ParamReply> {
    (pnu(), any::<u8>(), reply_kind()).prop_map(|(pnu, subindex, kind)| ParamReply {
        pnu,
        subindex,
        kind,
    })
}

/// The reply as the other side reads it back. Replies whose type travels with the value (reply
/// IDs 3 and 9-15) come back as a word when the dword's high word is 0: in 4 words, PWE1 = 0 is
/// how a word is carried.
fn as_read_back(reply: ParamReply) -> ParamReply {
    let narrow = |v: Value| match v {
        Value::Dword(d) if d >> 16 == 0 => Value::Word(d as u16),
        v => v,
    };
    let kind = match reply.kind {
        ReplyKind::Description(v) => ReplyKind::Description(narrow(v)),
        ReplyKind::ChangeReport { id, value } => ReplyKind::ChangeReport {
            id,
            value: narrow(value),
        },
        ReplyKind::Other { id, value } => ReplyKind::Other {
            id,
            value: narrow(value),
        },
        kind => kind,
    };
    ParamReply { kind, ..reply }
}

fn carries_dword(kind: ReplyKind) -> bool {
    kind.value().is_some_and(Value::is_dword)
}

/// A reply a correct drive gives to `task` (which is not `ParamTask::None`): same PNU and index,
/// a reply ID of the task's family, or a negative reply. `pick` chooses among those.
fn drive_reply(
    task: &ParamTask,
    pick: Index,
    word: u16,
    dword: u32,
    error: ErrorNumber,
) -> ParamReply {
    let read = [
        ReplyKind::Word(word),
        ReplyKind::Dword(dword),
        // G120/S110 answer plain tasks with the array reply IDs.
        ReplyKind::ArrayWord(word),
        ReplyKind::ArrayDword(dword),
    ];
    let mut kinds = match *task {
        ParamTask::None => unreachable!("no task, no reply"),
        ParamTask::Read { .. } | ParamTask::ReadArray { .. } => read.to_vec(),
        ParamTask::Write { value, .. } | ParamTask::WriteArray { value, .. } => match value {
            Value::Word(w) => vec![ReplyKind::Word(w), ReplyKind::ArrayWord(w)],
            Value::Dword(d) => vec![ReplyKind::Dword(d), ReplyKind::ArrayDword(d)],
        },
        ParamTask::ReadDescription { .. } => vec![
            ReplyKind::Description(Value::Word(word)),
            ReplyKind::Description(Value::Dword(dword)),
        ],
        ParamTask::ReadArrayLen { .. } => vec![ReplyKind::ElementCount(word)],
    };
    kinds.extend([ReplyKind::Error(error), ReplyKind::NoChangeRights]);
    ParamReply {
        pnu: task.pnu().unwrap(),
        subindex: task.subindex(),
        kind: *pick.get(&kinds),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn task_round_trips_over_four_words_and_variable_length(
        task in task(value()),
        mode in prop_oneof![Just(PkwMode::Four), Just(PkwMode::Variable)],
    ) {
        let mut words = [0u16; 4];
        prop_assert_eq!(task.encode(mode, &mut words), Ok(4));
        prop_assert_eq!(words[0] >> 12, u16::from(task.id()));
        prop_assert_eq!(ParamTask::decode(&words), Ok(task));
    }

    #[test]
    fn word_task_round_trips_over_three_words(task in task(word())) {
        let mut words = [0u16; 4];
        prop_assert_eq!(task.encode(PkwMode::Three, &mut words), Ok(3));
        prop_assert_eq!(ParamTask::decode(&words[..3]), Ok(task));
    }

    #[test]
    fn dword_task_is_refused_over_three_words_on_both_sides(task in dword_task()) {
        let mut words = [0u16; 4];
        prop_assert_eq!(
            task.encode(PkwMode::Three, &mut words),
            Err(PkwError::DwordOverThreeWords)
        );
        prop_assert_eq!(task.encode(PkwMode::Four, &mut words), Ok(4));
        prop_assert_eq!(ParamTask::decode(&words[..3]), Err(PkwError::DwordOverThreeWords));
    }

    #[test]
    fn no_task_fits_a_slave_without_parameter_channel(task in task(value())) {
        prop_assert_eq!(task.encode(PkwMode::None, &mut [0; 4]), Err(PkwError::NoChannel));
    }

    #[test]
    fn reply_round_trips_in_every_mode_that_fits_it(reply in reply()) {
        let mut words = [0u16; 4];
        let dword = carries_dword(reply.kind);
        for (mode, len) in [
            (PkwMode::Four, 4),
            (PkwMode::Variable, if dword { 4 } else { 3 }),
            (PkwMode::Three, 3),
        ] {
            if dword && mode == PkwMode::Three {
                prop_assert_eq!(reply.encode(mode, &mut words), Err(PkwError::DwordOverThreeWords));
                continue;
            }
            prop_assert_eq!(reply.encode(mode, &mut words), Ok(len));
            prop_assert_eq!(
                ParamReply::decode(&words[..len]),
                Ok(as_read_back(reply)),
                "{:?}",
                mode
            );
        }
        prop_assert_eq!(reply.encode(PkwMode::None, &mut words), Err(PkwError::NoChannel));
    }

    #[test]
    fn drive_reply_answers_its_task_and_no_other(
        task in task(value()).prop_filter("a task", |t| *t != ParamTask::None),
        pick in any::<Index>(),
        word in any::<u16>(),
        dword in any::<u32>(),
        error in param_error(),
        other_pnu in 1u16..=u16::MAX,
        other_index in 1u8..=u8::MAX,
    ) {
        // Through the wire, as the master sees it.
        let mut words = [0u16; 4];
        let sent = drive_reply(&task, pick, word, dword, error);
        sent.encode(PkwMode::Four, &mut words).unwrap();
        let reply = ParamReply::decode(&words).unwrap();
        prop_assert!(reply.answers(&task), "{:?} to {:?}", reply, task);

        let pnu = task.pnu().unwrap();
        let elsewhere = ParamReply {
            pnu: Pnu::from_u16(pnu.get().wrapping_add(other_pnu)),
            ..reply
        };
        prop_assert!(!elsewhere.answers(&task), "another PNU");
        let busy = ParamReply { kind: ReplyKind::NotYet, ..reply };
        prop_assert!(!busy.answers(&task), "reply ID 0 means busy");
        if matches!(
            task,
            ParamTask::ReadArray { .. }
                | ParamTask::WriteArray { .. }
                | ParamTask::ReadDescription { .. }
        ) {
            let other = ParamReply { subindex: reply.subindex.wrapping_add(other_index), ..reply };
            prop_assert!(!other.answers(&task), "another index");
        }
        prop_assert!(!reply.answers(&ParamTask::None));
    }

    #[test]
    fn pnu_round_trips_through_pke_and_ind(p in pnu()) {
        prop_assert_eq!(Pnu::from_parts(p.low(), p.ind_high()), Some(p));
    }
}

// PZD (USS.md section 7).

/// Any float but NaN, with plenty in the -300 % .. +300 % range.
fn percent() -> impl Strategy<Value = f32> {
    use prop::num::f32::{INFINITE, NEGATIVE, NORMAL, POSITIVE, SUBNORMAL, ZERO};
    prop_oneof![
        3 => -300.0f32..300.0,
        1 => POSITIVE | NEGATIVE | NORMAL | SUBNORMAL | ZERO | INFINITE,
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn setpoint_from_percent_is_monotonic_rounded_and_saturating(a in percent(), b in percent()) {
        let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
        prop_assert!(Setpoint::from_percent(lo) <= Setpoint::from_percent(hi));
        for p in [a, b] {
            let raw = Setpoint::from_percent(p).raw();
            let exact = f64::from(p) * 16384.0 / 100.0;
            if exact >= 32767.0 {
                prop_assert_eq!(raw, i16::MAX);
            } else if exact <= -32768.0 {
                prop_assert_eq!(raw, i16::MIN);
            } else {
                prop_assert!((f64::from(raw) - exact).abs() <= 0.51, "{} % gave {}", p, raw);
            }
        }
    }

    #[test]
    fn setpoint_hz_round_trips_within_one_lsb(raw in any::<i16>(), reference_hz in 1.0f32..=650.0) {
        let hz = Setpoint::from_raw(raw).hz(reference_hz);
        let back = Setpoint::from_hz(hz, reference_hz).raw();
        prop_assert!(
            (i32::from(back) - i32::from(raw)).abs() <= 1,
            "{} -> {} Hz -> {}",
            raw,
            hz,
            back
        );
    }

    #[test]
    fn frequency_round_trips_within_one_lsb(
        fraction in -2.0f32..1.99,
        reference_hz in 1.0f32..=650.0,
    ) {
        let hz = fraction * reference_hz;
        let lsb = reference_hz / 16384.0;
        let back = Setpoint::from_hz(hz, reference_hz).hz(reference_hz);
        prop_assert!((back - hz).abs() <= lsb, "{} Hz -> {} Hz", hz, back);
    }
}

// ---------------------------------------------------------------------------------------------
// Parameter notation (USS.md section 6)
// ---------------------------------------------------------------------------------------------

proptest! {
    #[test]
    fn parameter_references_round_trip_through_the_manuals_notation(
        pnu in any::<u16>(),
        index in proptest::option::of(0u8..=254),
        letter in prop_oneof![Just(""), Just("P"), Just("p"), Just("r")],
        dot in any::<bool>(),
    ) {
        let text = match (index, dot) {
            (Some(i), true) => format!("{letter}{pnu:04}.{i}"),
            (Some(i), false) => format!("{letter}{pnu}[{i}]"),
            (None, _) => format!("{letter}{pnu}"),
        };
        let parsed: ParamRef = text.parse().unwrap();
        prop_assert_eq!(parsed.pnu.get(), pnu);
        prop_assert_eq!(parsed.index.map(Subindex::get), index);
        let again: ParamRef = parsed.to_string().parse().unwrap();
        prop_assert_eq!((again.pnu, again.index), (parsed.pnu, parsed.index));
    }

    #[test]
    fn any_text_parses_or_is_refused_without_panicking(text in "\\PC{0,12}") {
        let _ = text.parse::<ParamRef>();
    }
}
