//! Whole telegrams: `STX LGE ADR [PKW][PZD] BCC` (USS.md section 3).

use crate::adr::Adr;
use thiserror::Error;

/// Start of text.
pub const STX: u8 = 0x02;
/// The most net bytes a telegram carries (LGE <= 254).
pub const MAX_NET_BYTES: usize = 252;
/// The longest telegram on the wire: STX, LGE, ADR, 252 net bytes, BCC.
pub const MAX_TELEGRAM_BYTES: usize = MAX_NET_BYTES + 4;
/// The most PZD words a slave carries (S110: 16).
pub const MAX_PZD_WORDS: usize = 16;
/// The most PKW words a telegram carries.
pub const MAX_PKW_WORDS: usize = 4;

/// XOR of every byte given: the block check character when given STX through the last net byte
/// (USS.md section 3; STX is included).
pub fn bcc(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |acc, b| acc ^ b)
}

/// The PKW channel length a slave is set to (P2013, USS.md section 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PkwMode {
    /// P2013 = 0: no parameter channel.
    None,
    /// P2013 = 3: three words; only word values fit.
    Three,
    /// P2013 = 4: four words.
    Four,
    /// P2013 = 127: the master sends 4 words, the reply has 3 or 4 by the value's type.
    Variable,
}

impl PkwMode {
    /// PKW words the master sends in every request.
    pub const fn request_words(self) -> usize {
        match self {
            Self::None => 0,
            Self::Three => 3,
            Self::Four | Self::Variable => 4,
        }
    }

    /// Whether a double-word value (a float parameter) fits in the channel: not in three words.
    pub const fn carries_dword(self) -> bool {
        matches!(self, Self::Four | Self::Variable)
    }

    /// Whether a reply carrying `words` PKW words has a length this mode allows.
    pub const fn accepts_reply_words(self, words: usize) -> bool {
        match self {
            Self::None => words == 0,
            Self::Three => words == 3,
            Self::Four => words == 4,
            Self::Variable => words == 3 || words == 4,
        }
    }

    /// The mode for a P2013 setting.
    pub const fn from_p2013(value: u16) -> Option<Self> {
        match value {
            0 => Some(Self::None),
            3 => Some(Self::Three),
            4 => Some(Self::Four),
            127 => Some(Self::Variable),
            _ => None,
        }
    }

    /// The P2013 setting for this mode.
    pub const fn p2013(self) -> u16 {
        match self {
            Self::None => 0,
            Self::Three => 3,
            Self::Four => 4,
            Self::Variable => 127,
        }
    }
}

/// The number of PZD words a slave exchanges, 0..=16 (P2012, USS.md section 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct PzdCount(u8);

impl PzdCount {
    pub const fn new(words: usize) -> Result<Self, LayoutError> {
        if words <= MAX_PZD_WORDS {
            Ok(Self(words as u8))
        } else {
            Err(LayoutError::PzdWords(words))
        }
    }

    pub const fn get(self) -> usize {
        self.0 as usize
    }
}

/// A slave's telegram shape: its PKW mode and PZD word count, which both sides must agree on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Layout {
    pub pkw: PkwMode,
    pub pzd: PzdCount,
}

impl Layout {
    pub const fn new(pkw: PkwMode, pzd: PzdCount) -> Self {
        Self { pkw, pzd }
    }

    /// Net bytes of every request to this slave.
    pub const fn request_net_bytes(self) -> usize {
        (self.pkw.request_words() + self.pzd.get()) * 2
    }

    /// Net bytes of the longest reply this slave sends.
    pub const fn max_reply_net_bytes(self) -> usize {
        self.request_net_bytes()
    }
}

/// Why words do not make a telegram of a given shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum LayoutError {
    #[error("{0} PZD words requested: a telegram carries at most 16")]
    PzdWords(usize),
    #[error("{0} PKW words given: the parameter channel has 0, 3 or 4 words")]
    PkwWords(usize),
    #[error("odd number of net bytes ({0}): PKW and PZD are whole words")]
    OddNetBytes(usize),
    #[error(
        "reply has {net_bytes} net bytes, which does not fit {pzd} PZD words with the slave's PKW mode"
    )]
    Shape { net_bytes: usize, pzd: usize },
}

/// Why a telegram could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum EncodeError {
    #[error(transparent)]
    Layout(#[from] LayoutError),
    #[error("{0} net bytes do not fit a telegram (at most 252)")]
    TooLong(usize),
    #[error("buffer of {available} bytes is too small for a telegram of {needed}")]
    BufferTooSmall { needed: usize, available: usize },
}

/// Encodes a telegram of arbitrary net bytes into `buf` and returns its length. Use this for
/// special and mirror telegrams; [`encode`] builds ordinary PKW/PZD telegrams.
pub fn encode_raw(buf: &mut [u8], adr: Adr, net: &[u8]) -> Result<usize, EncodeError> {
    if net.len() > MAX_NET_BYTES {
        return Err(EncodeError::TooLong(net.len()));
    }
    let len = net.len() + 4;
    if buf.len() < len {
        return Err(EncodeError::BufferTooSmall {
            needed: len,
            available: buf.len(),
        });
    }
    buf[0] = STX;
    buf[1] = (net.len() + 2) as u8;
    buf[2] = adr.to_byte();
    buf[3..3 + net.len()].copy_from_slice(net);
    buf[len - 1] = bcc(&buf[..len - 1]);
    Ok(len)
}

/// Encodes a telegram of PKW words (0, 3 or 4) followed by PZD words (0..=16), every word high
/// byte first (USS.md section 3), into `buf` and returns its length.
pub fn encode(buf: &mut [u8], adr: Adr, pkw: &[u16], pzd: &[u16]) -> Result<usize, EncodeError> {
    if !matches!(pkw.len(), 0 | 3 | 4) {
        return Err(LayoutError::PkwWords(pkw.len()).into());
    }
    if pzd.len() > MAX_PZD_WORDS {
        return Err(LayoutError::PzdWords(pzd.len()).into());
    }
    let net = (pkw.len() + pzd.len()) * 2;
    let len = net + 4;
    if buf.len() < len {
        return Err(EncodeError::BufferTooSmall {
            needed: len,
            available: buf.len(),
        });
    }
    buf[0] = STX;
    buf[1] = (net + 2) as u8;
    buf[2] = adr.to_byte();
    for (i, w) in pkw.iter().chain(pzd).enumerate() {
        buf[3 + 2 * i..5 + 2 * i].copy_from_slice(&w.to_be_bytes());
    }
    buf[len - 1] = bcc(&buf[..len - 1]);
    Ok(len)
}

/// Why bytes are not a valid telegram.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum DecodeError {
    #[error("telegram of {0} bytes is too short (at least STX, LGE, ADR, BCC)")]
    TooShort(usize),
    #[error("first byte 0x{0:02X} is not STX (0x02)")]
    NoStx(u8),
    #[error("LGE {0} is out of range 2..=254")]
    BadLge(u8),
    #[error("LGE {lge} says {} bytes but {len} were given", *lge as usize + 2)]
    LengthMismatch { lge: u8, len: usize },
    #[error("BCC 0x{actual:02X} received, 0x{expected:02X} computed")]
    Bcc { expected: u8, actual: u8 },
}

/// A complete telegram whose STX, LGE and BCC have been checked. Borrowed, never copied.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Telegram<'a> {
    bytes: &'a [u8],
}

impl<'a> Telegram<'a> {
    /// Validates a whole telegram.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, DecodeError> {
        if bytes.len() < 4 {
            return Err(DecodeError::TooShort(bytes.len()));
        }
        if bytes[0] != STX {
            return Err(DecodeError::NoStx(bytes[0]));
        }
        let lge = bytes[1];
        if !(2..=254).contains(&lge) {
            return Err(DecodeError::BadLge(lge));
        }
        if lge as usize + 2 != bytes.len() {
            return Err(DecodeError::LengthMismatch {
                lge,
                len: bytes.len(),
            });
        }
        let (body, last) = bytes.split_at(bytes.len() - 1);
        let expected = bcc(body);
        if expected != last[0] {
            return Err(DecodeError::Bcc {
                expected,
                actual: last[0],
            });
        }
        Ok(Self { bytes })
    }

    /// A telegram the receive framer took whole and checked as the bytes came (STX, LGE in
    /// range, its length, BCC): not checked a second time.
    pub(crate) fn checked_by_framer(bytes: &'a [u8]) -> Self {
        debug_assert_eq!(Self::parse(bytes), Ok(Self { bytes }));
        Self { bytes }
    }

    /// The whole telegram, STX through BCC.
    pub fn as_bytes(&self) -> &'a [u8] {
        self.bytes
    }

    pub fn lge(&self) -> u8 {
        self.bytes[1]
    }

    pub fn adr(&self) -> Adr {
        Adr::from_byte(self.bytes[2])
    }

    /// The net bytes between ADR and BCC.
    pub fn net(&self) -> &'a [u8] {
        &self.bytes[3..self.bytes.len() - 1]
    }

    /// Splits the net data into PKW and PZD words for a slave of the given layout. The PKW length
    /// is taken from LGE, never assumed (USS.md section 3): with [`PkwMode::Variable`] a reply may
    /// carry 3 or 4 PKW words.
    pub fn words(&self, layout: Layout) -> Result<Words, LayoutError> {
        let net = self.net();
        if !net.len().is_multiple_of(2) {
            return Err(LayoutError::OddNetBytes(net.len()));
        }
        let total = net.len() / 2;
        let pzd = layout.pzd.get();
        let shape = LayoutError::Shape {
            net_bytes: net.len(),
            pzd,
        };
        let pkw_words = total.checked_sub(pzd).ok_or(shape)?;
        if !layout.pkw.accepts_reply_words(pkw_words) {
            return Err(shape);
        }
        let mut words = Words::default();
        for (i, pair) in net.chunks_exact(2).enumerate() {
            let w = u16::from_be_bytes([pair[0], pair[1]]);
            if i < pkw_words {
                words.pkw[i] = w;
            } else {
                words.pzd[i - pkw_words] = w;
            }
        }
        words.pkw_len = pkw_words as u8;
        words.pzd_len = pzd as u8;
        Ok(words)
    }
}

/// The PKW and PZD words of one telegram, copied out in a fixed-size, allocation-free form.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Words {
    pkw: [u16; MAX_PKW_WORDS],
    pkw_len: u8,
    pzd: [u16; MAX_PZD_WORDS],
    pzd_len: u8,
}

impl Words {
    pub fn pkw(&self) -> &[u16] {
        &self.pkw[..self.pkw_len as usize]
    }

    pub fn pzd(&self) -> &[u16] {
        &self.pzd[..self.pzd_len as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adr::Address;

    fn adr(a: u8) -> Adr {
        Adr::to(Address::new(a).unwrap())
    }

    fn layout(pkw: PkwMode, pzd: usize) -> Layout {
        Layout::new(pkw, PzdCount::new(pzd).unwrap())
    }

    #[test]
    fn bcc_includes_stx() {
        // USS.md section 3: STX 02, LGE 0E, ADR 04 gives a running XOR of 08.
        assert_eq!(bcc(&[0x02, 0x0E, 0x04]), 0x08);
    }

    #[test]
    fn encodes_pkw4_pzd2_high_byte_first() {
        // Read P2000 (PKE 0x1000, IND 0x8000) with STW1 0x047F and setpoint 0x199A to slave 4.
        let mut buf = [0u8; 32];
        let n = encode(&mut buf, adr(4), &[0x1000, 0x8000, 0, 0], &[0x047F, 0x199A]).unwrap();
        let body = [
            0x02, 0x0E, 0x04, 0x10, 0x00, 0x80, 0x00, 0x00, 0x00, 0x00, 0x00, 0x04, 0x7F, 0x19,
            0x9A,
        ];
        assert_eq!(n, 16);
        assert_eq!(&buf[..15], &body);
        assert_eq!(buf[15], bcc(&body));
        let t = Telegram::parse(&buf[..n]).unwrap();
        assert_eq!(t.adr(), adr(4));
        let w = t.words(layout(PkwMode::Four, 2)).unwrap();
        assert_eq!(w.pkw(), &[0x1000, 0x8000, 0, 0]);
        assert_eq!(w.pzd(), &[0x047F, 0x199A]);
    }

    /// The MM420 start-up of USS.md section 7 as USS telegrams (PKW 0, PZD 2) to and from slave 0.
    #[test]
    fn mm420_start_up_trace_encodes_byte_exact() {
        let mut buf = [0u8; 16];
        let n = encode(&mut buf, adr(0), &[], &[0x0476, 0x0000]).unwrap();
        assert_eq!(&buf[..n], &[0x02, 0x06, 0x00, 0x04, 0x76, 0x00, 0x00, 0x76]);
        let n = encode(&mut buf, adr(0), &[], &[0xFB41, 0x0000]).unwrap();
        assert_eq!(&buf[..n], &[0x02, 0x06, 0x00, 0xFB, 0x41, 0x00, 0x00, 0xBE]);
        let n = encode(&mut buf, adr(0), &[], &[0x047F, 0x199A]).unwrap();
        assert_eq!(&buf[..n], &[0x02, 0x06, 0x00, 0x04, 0x7F, 0x19, 0x9A, 0xFC]);
        let reply = [0x02, 0x06, 0x00, 0x6B, 0x37, 0x19, 0x9A, 0xDB];
        let t = Telegram::parse(&reply).unwrap();
        assert_eq!(
            t.words(layout(PkwMode::None, 2)).unwrap().pzd(),
            &[0x6B37, 0x199A]
        );
    }

    #[test]
    fn variable_pkw_reply_is_split_by_lge() {
        let mut buf = [0u8; 32];
        let l = layout(PkwMode::Variable, 2);
        let n = encode(&mut buf, adr(1), &[0x1000, 0, 7], &[0xFB34, 0]).unwrap();
        let w = Telegram::parse(&buf[..n]).unwrap().words(l).unwrap();
        assert_eq!(w.pkw(), &[0x1000, 0, 7]);
        let n = encode(&mut buf, adr(1), &[0x2000, 0, 0x4248, 0], &[0xFB34, 0]).unwrap();
        let w = Telegram::parse(&buf[..n]).unwrap().words(l).unwrap();
        assert_eq!(w.pkw(), &[0x2000, 0, 0x4248, 0]);
        assert_eq!(w.pzd(), &[0xFB34, 0]);
    }

    #[test]
    fn wrong_shapes_are_refused() {
        let mut buf = [0u8; 64];
        assert_eq!(
            encode(&mut buf, adr(1), &[1, 2], &[]),
            Err(EncodeError::Layout(LayoutError::PkwWords(2)))
        );
        assert_eq!(
            encode(&mut buf, adr(1), &[], &[0; 17]),
            Err(EncodeError::Layout(LayoutError::PzdWords(17)))
        );
        assert_eq!(
            encode(&mut buf[..10], adr(1), &[0; 4], &[]),
            Err(EncodeError::BufferTooSmall {
                needed: 12,
                available: 10
            })
        );
        assert_eq!(
            encode_raw(&mut [0u8; 300], adr(1), &[0; 253]),
            Err(EncodeError::TooLong(253))
        );
        let n = encode(&mut buf, adr(1), &[0; 3], &[0; 2]).unwrap();
        let t = Telegram::parse(&buf[..n]).unwrap();
        assert_eq!(
            t.words(layout(PkwMode::Four, 2)),
            Err(LayoutError::Shape {
                net_bytes: 10,
                pzd: 2
            })
        );
        assert!(t.words(layout(PkwMode::Three, 2)).is_ok());
        assert!(t.words(layout(PkwMode::None, 6)).is_err());
    }

    #[test]
    fn parse_rejects_each_fault() {
        let mut buf = [0u8; 16];
        let n = encode(&mut buf, adr(3), &[], &[0x047E, 0]).unwrap();
        let good = &buf[..n];
        assert!(Telegram::parse(good).is_ok());
        assert_eq!(Telegram::parse(&good[..3]), Err(DecodeError::TooShort(3)));
        let mut bad = [0u8; 8];
        bad.copy_from_slice(good);
        bad[7] ^= 1;
        assert!(matches!(
            Telegram::parse(&bad),
            Err(DecodeError::Bcc { .. })
        ));
        bad.copy_from_slice(good);
        bad[0] = 0x03;
        assert_eq!(Telegram::parse(&bad), Err(DecodeError::NoStx(3)));
        bad.copy_from_slice(good);
        bad[1] = 7;
        assert_eq!(
            Telegram::parse(&bad),
            Err(DecodeError::LengthMismatch { lge: 7, len: 8 })
        );
        bad[1] = 255;
        assert_eq!(Telegram::parse(&bad), Err(DecodeError::BadLge(255)));
    }

    #[test]
    fn longest_telegram_is_256_bytes() {
        let mut buf = [0u8; MAX_TELEGRAM_BYTES];
        let n = encode_raw(&mut buf, adr(31), &[0xAA; MAX_NET_BYTES]).unwrap();
        assert_eq!(n, 256);
        assert_eq!(buf[1], 254);
        assert_eq!(Telegram::parse(&buf).unwrap().net().len(), 252);
    }

    #[test]
    fn p2013_codes() {
        for m in [
            PkwMode::None,
            PkwMode::Three,
            PkwMode::Four,
            PkwMode::Variable,
        ] {
            assert_eq!(PkwMode::from_p2013(m.p2013()), Some(m));
        }
        assert_eq!(PkwMode::from_p2013(2), None);
    }
}
