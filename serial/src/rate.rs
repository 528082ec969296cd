//! The character rate a serial port really runs at (issue 22). termios says what was asked;
//! the port may make something else of it: a `cp210x` adapter maps each rate to the nearest its clock
//! makes (187500 becomes 230400) and says so in termios; an 8250/16550 keeps the requested
//! rate in termios but divides its base (115200 for a 1.8432 MHz crystal) by the nearest whole
//! divisor (76800 becomes 57600), and a rate above its base is refused with the old rate kept.
//! Drives on a rate more than 2 % off never answer, so ussd refuses such a port and says what it
//! made of the rate.

use core::fmt;

/// What the port says after the rate was set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReadBack {
    /// The output rate in termios (`TCGETS2`'s `c_ospeed`).
    pub termios: u32,
    /// An 8250-family UART's divisor base (`TIOCGSERIAL`'s `baud_base`), if the driver has one.
    pub baud_base: Option<u32>,
}

/// The largest deviation the drives tolerate (USS.md section 2: a UART samples mid-bit; 2 %
/// leaves room for the drive's own error over 11 bits).
pub const MAX_DEVIATION_PERCENT: f64 = 2.0;

/// A rate the port cannot make closely enough.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RateOff {
    pub requested: u32,
    pub obtained: u32,
    /// The divisor base that explains it, for an 8250-family UART.
    pub baud_base: Option<u32>,
}

impl fmt::Display for RateOff {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "the port runs {} baud for the {} asked ({:+.1} %, more than {MAX_DEVIATION_PERCENT} % off: the drives would not answer)",
            self.obtained,
            self.requested,
            deviation_percent(self.requested, self.obtained)
        )?;
        if let Some(base) = self.baud_base {
            write!(
                f,
                "; its divisor base is {base} baud, so it makes {base}/n only"
            )?;
        }
        Ok(())
    }
}

fn deviation_percent(requested: u32, obtained: u32) -> f64 {
    (f64::from(obtained) - f64::from(requested)) / f64::from(requested) * 100.0
}

/// The rate the port runs at, from what it reads back after `requested` was set: termios's,
/// made exact with an 8250's divisor (the nearest whole divisor of its base, as the kernel's
/// `DIV_ROUND_CLOSEST`). `Err` when it is more than [`MAX_DEVIATION_PERCENT`] off.
pub fn obtained(requested: u32, read_back: ReadBack) -> Result<u32, RateOff> {
    let rate = match read_back.baud_base {
        Some(base) if base > 0 && read_back.termios > 0 => {
            let divisor = (base + read_back.termios / 2) / read_back.termios;
            base / divisor.max(1)
        }
        _ => read_back.termios,
    };
    if deviation_percent(requested, rate).abs() > MAX_DEVIATION_PERCENT {
        return Err(RateOff {
            requested,
            obtained: rate,
            baud_base: read_back.baud_base,
        });
    }
    Ok(rate)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The kernel's `cp210x_get_an205_rate` (drivers/usb/serial/cp210x.c): what a CP2102
    /// runs at, and writes back into termios, for a requested rate.
    fn cp2102(baud: u32) -> u32 {
        const TABLE: &[(u32, u32)] = &[
            (300, 300),
            (600, 600),
            (1200, 1200),
            (1800, 1800),
            (2400, 2400),
            (4000, 4000),
            (4803, 4800),
            (7207, 7200),
            (9612, 9600),
            (14428, 14400),
            (16062, 16000),
            (19250, 19200),
            (28912, 28800),
            (38601, 38400),
            (51558, 51200),
            (56280, 56000),
            (58053, 57600),
            (64111, 64000),
            (77608, 76800),
            (117_028, 115_200),
            (129_347, 128_000),
            (156_868, 153_600),
            (237_832, 230_400),
            (254_234, 250_000),
            (273_066, 256_000),
            (491_520, 460_800),
            (567_138, 500_000),
            (670_254, 576_000),
        ];
        TABLE
            .iter()
            .find(|&&(upto, _)| baud <= upto)
            .map_or(921_600, |&(_, rate)| rate)
    }

    /// What an 8250 with a 1.8432 MHz crystal reads back: the requested rate while it is at
    /// most its base (the divisor is applied, not written back), else the old one (9600).
    fn uart_1_8432_mhz(baud: u32) -> ReadBack {
        ReadBack {
            termios: if baud <= 115_200 { baud } else { 9600 },
            baud_base: Some(115_200),
        }
    }

    /// The rates USS names (USS.md section 2).
    const USS_RATES: [u32; 10] = [
        300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 187_500,
    ];

    #[test]
    fn a_cp2102_makes_every_uss_rate_but_187500_which_it_turns_into_230400() {
        for rate in USS_RATES {
            let read_back = ReadBack {
                termios: cp2102(rate),
                baud_base: None,
            };
            if rate == 187_500 {
                let off = obtained(rate, read_back).unwrap_err();
                assert_eq!(off.obtained, 230_400);
                assert_eq!(
                    off.to_string(),
                    "the port runs 230400 baud for the 187500 asked (+22.9 %, more than 2 % off: \
                     the drives would not answer)"
                );
            } else {
                assert_eq!(obtained(rate, read_back), Ok(rate), "{rate}");
            }
        }
        // 76800 (a rate some drives offer) and 93750 are made close enough or not.
        assert_eq!(
            obtained(
                76_800,
                ReadBack {
                    termios: cp2102(76_800),
                    baud_base: None
                }
            ),
            Ok(76_800)
        );
        assert!(
            obtained(
                93_750,
                ReadBack {
                    termios: cp2102(93_750),
                    baud_base: None
                }
            )
            .is_err()
        );
    }

    #[test]
    fn a_16550_at_1_8432_mhz_keeps_the_old_rate_above_its_base_and_rounds_its_divisor() {
        for rate in USS_RATES {
            let result = obtained(rate, uart_1_8432_mhz(rate));
            if rate == 187_500 {
                let off = result.unwrap_err();
                assert_eq!(off.obtained, 9600, "the old rate kept");
                assert!(
                    off.to_string()
                        .ends_with("its divisor base is 115200 baud, so it makes 115200/n only"),
                    "{off}"
                );
            } else {
                assert_eq!(result, Ok(rate), "{rate}");
            }
        }
        // 76800: 115200 / 76800 = 1.5, the divisor rounds to 2: 57600.
        let off = obtained(76_800, uart_1_8432_mhz(76_800)).unwrap_err();
        assert_eq!(off.obtained, 57_600);
        // A 14.7456 MHz UART (base 921600) makes 187500 within 2 % (divisor 5: 184320).
        assert_eq!(
            obtained(
                187_500,
                ReadBack {
                    termios: 187_500,
                    baud_base: Some(921_600)
                }
            ),
            Ok(184_320)
        );
    }

    proptest! {
        #[test]
        fn the_obtained_rate_is_accepted_exactly_when_within_2_percent(
            requested in 300u32..=1_000_000,
            termios in 1u32..=2_000_000,
            base in proptest::option::of(1u32..=4_000_000),
        ) {
            let read_back = ReadBack { termios, baud_base: base };
            match obtained(requested, read_back) {
                Ok(rate) => prop_assert!(deviation_percent(requested, rate).abs() <= 2.0),
                Err(off) => {
                    prop_assert!(deviation_percent(requested, off.obtained).abs() > 2.0);
                    prop_assert_eq!(off.requested, requested);
                }
            }
        }
    }
}
