//! The one definition of each session quantity arthrosim reports: when the probe is in
//! contact and its normal force ([`contact`]), which device tick (and so which region,
//! probing and phase) a physics step belongs to ([`matching`]), and the study's per-region
//! metrics built from them ([`summary`]: mean normal force in contact, probe displacement).
//! Region and phase codes themselves are `msgs::protocol`.
//!
//! Data comes in as the physics node's contact frames and the haptic node's device states,
//! live (the launcher's summary) or read back from a recording (`recordings`' study export
//! and session summary, the gap diagnosis's session trials); every consumer calls the
//! functions here, so they report the same numbers for the same session.

pub mod contact;
pub mod matching;
pub mod summary;

pub use contact::ContactSample;
pub use matching::{Annotation, Annotations};
pub use summary::{summarize, RegionSummary, SessionRecord, SessionSummary};
