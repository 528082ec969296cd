//! pcapng files of captured telegrams, for Wireshark with `tools/wireshark/uss.lua`: one
//! interface of link type `USER0` (147) with nanosecond time stamps of the wall clock; each
//! telegram is a packet of an 8-byte header ([`header`]) and the bytes as they were on the wire;
//! the direction is also in the packet's `epb_flags` (outbound: request, inbound: reply).

use pcap_file::DataLink;
use pcap_file::pcapng::PcapNgWriter;
use pcap_file::pcapng::blocks::enhanced_packet::{EnhancedPacketBlock, EnhancedPacketOption};
use pcap_file::pcapng::blocks::interface_description::{
    InterfaceDescriptionBlock, InterfaceDescriptionOption,
};
use pcap_file::pcapng::blocks::section_header::SectionHeaderBlock;
use pcap_file::{Endianness, PcapError};
use std::borrow::Cow;
use std::io::Write;
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use uss_client::uss_shm_types::{Direction, TelegramRecord};

/// Version of the packet header; the dissector checks it.
pub const HEADER_VERSION: u8 = 1;
/// Bytes of the packet header.
pub const HEADER_LEN: usize = 8;

/// The packet header: version, direction (0 request, 1 reply), outcome (0 good, else the
/// failure code of `uss_shm_types::LastFailure`), drive address, PKW mode (P2013: 0, 3, 4,
/// 127), PZD words, flags (bit 0 truncated, bit 1 carries a task), 0.
pub fn header(r: &TelegramRecord) -> [u8; HEADER_LEN] {
    [
        HEADER_VERSION,
        r.direction,
        r.outcome,
        r.address,
        r.pkw,
        r.pzd,
        r.flags,
        0,
    ]
}

/// Writes captured telegrams to a pcapng stream.
pub struct Writer<W: Write> {
    writer: PcapNgWriter<W>,
    /// Wall clock minus `CLOCK_MONOTONIC`, ns: the records' times are monotonic.
    wall_offset_ns: i128,
}

impl<W: Write> Writer<W> {
    /// A section (little-endian) with the one interface; `wall_offset_ns` turns the records'
    /// `CLOCK_MONOTONIC` times into wall-clock times.
    pub fn new(out: W, wall_offset_ns: i128) -> Result<Self, PcapError> {
        let section = SectionHeaderBlock {
            endianness: Endianness::Little,
            ..Default::default()
        };
        let mut writer = PcapNgWriter::with_section_header(out, section)?;
        writer.write_pcapng_block(InterfaceDescriptionBlock {
            linktype: DataLink::USER0,
            snaplen: 0,
            options: vec![
                InterfaceDescriptionOption::IfName(Cow::Borrowed("uss")),
                InterfaceDescriptionOption::IfTsResol(9),
            ],
        })?;
        Ok(Self {
            writer,
            wall_offset_ns,
        })
    }

    /// One telegram.
    pub fn write(&mut self, r: &TelegramRecord) -> Result<(), PcapError> {
        let mut data = header(r).to_vec();
        data.extend_from_slice(r.bytes());
        let at = (i128::from(r.start_ns) + self.wall_offset_ns).max(0);
        let flags = match r.direction() {
            Ok(Direction::Request) => 2,
            _ => 1,
        };
        self.writer.write_pcapng_block(EnhancedPacketBlock {
            interface_id: 0,
            timestamp: Duration::from_nanos(u64::try_from(at).unwrap_or(u64::MAX)),
            original_len: data.len() as u32,
            data: Cow::Owned(data),
            options: vec![EnhancedPacketOption::Flags(flags)],
        })?;
        Ok(())
    }

    pub fn into_inner(self) -> W {
        self.writer.into_inner()
    }
}

/// Wall clock minus `CLOCK_MONOTONIC` now, ns.
pub fn wall_offset_ns() -> i128 {
    let wall = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i128);
    wall - i128::from(uss_client::monotonic_ns())
}
