//! The study's probing protocol as the haptic node annotates it on every device state
//! (`DeviceState.region`, `.probing_index`, `.phase`): the one definition of the region and
//! phase codes every reader of a session (summary, export, gap diagnosis, viewers) decodes.

use serde::{Deserialize, Serialize};

/// Probing region of the meniscus, as coded in `DeviceState.region` (0 = unlabelled).
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Region {
    Posterior = 1,
    Mid = 2,
    Anterior = 3,
}

/// How a session quantity names a device state without a region annotation.
pub const UNLABELLED: &str = "unlabelled";

impl Region {
    /// The study's order.
    pub const ALL: [Region; 3] = [Region::Posterior, Region::Mid, Region::Anterior];

    /// The region of a `DeviceState.region` code; None for 0 (unlabelled) and unknown codes.
    pub fn from_code(code: u32) -> Option<Region> {
        match code {
            1 => Some(Region::Posterior),
            2 => Some(Region::Mid),
            3 => Some(Region::Anterior),
            _ => None,
        }
    }

    /// Parses a region name (case and surrounding blanks ignored).
    pub fn parse(s: &str) -> Option<Region> {
        Region::ALL
            .into_iter()
            .find(|r| r.name() == s.trim().to_ascii_lowercase())
    }

    pub fn name(self) -> &'static str {
        match self {
            Region::Posterior => "posterior",
            Region::Mid => "mid",
            Region::Anterior => "anterior",
        }
    }

    pub fn code(self) -> u32 {
        self as u32
    }

    /// Name of a region code: the region's name, or [`UNLABELLED`].
    pub fn name_of_code(code: u32) -> &'static str {
        Region::from_code(code).map_or(UNLABELLED, Region::name)
    }
}

/// Protocol phase of the operator's hand, as coded in `DeviceState.phase`.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    Idle = 0,
    /// Moving to the site's hover point and down to the surface.
    Approach = 1,
    /// Pushing past the undeformed surface.
    Press = 2,
    /// Holding the pressed position.
    Hold = 3,
    /// Withdrawing to the hover point.
    Release = 4,
}

impl Phase {
    pub const ALL: [Phase; 5] = [
        Phase::Idle,
        Phase::Approach,
        Phase::Press,
        Phase::Hold,
        Phase::Release,
    ];

    /// The phase of a `DeviceState.phase` code; unknown codes are `Idle`.
    pub fn from_code(code: u32) -> Phase {
        Phase::ALL
            .into_iter()
            .find(|p| *p as u32 == code)
            .unwrap_or(Phase::Idle)
    }

    pub fn name(self) -> &'static str {
        match self {
            Phase::Idle => "idle",
            Phase::Approach => "approach",
            Phase::Press => "press",
            Phase::Hold => "hold",
            Phase::Release => "release",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_and_unknown_codes_are_unlabelled() {
        for r in Region::ALL {
            assert_eq!(Region::from_code(r.code()), Some(r));
            assert_eq!(
                Region::parse(&format!(" {} ", r.name().to_uppercase())),
                Some(r)
            );
        }
        assert_eq!(Region::from_code(0), None);
        assert_eq!(Region::name_of_code(7), UNLABELLED);
        for p in Phase::ALL {
            assert_eq!(Phase::from_code(p as u32), p);
        }
        assert_eq!(Phase::from_code(99), Phase::Idle);
    }
}
