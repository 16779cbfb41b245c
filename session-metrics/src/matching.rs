//! Step↔tick matching: which device tick (and so which protocol region, probing and phase) a
//! physics step belongs to. The one rule: a step belongs to the device state it consumed,
//! `ContactFrame.device_sequence_used`, not to the tick nearest in time.

use msgs::protocol::{Phase, Region};

/// The protocol annotation of a device tick (`DeviceState.region`, `.probing_index`, `.phase`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Annotation {
    /// Device tick sequence from which this annotation holds.
    pub sequence: u64,
    pub region: u32,
    pub probing_index: u32,
    pub phase: u32,
}

impl Annotation {
    pub fn region(&self) -> Option<Region> {
        Region::from_code(self.region)
    }
    pub fn phase(&self) -> Phase {
        Phase::from_code(self.phase)
    }
}

/// The device stream's annotations as a step function of the tick sequence: only the change
/// points are kept, so a whole session fits in a few hundred entries.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Annotations {
    points: Vec<Annotation>,
    last_sequence: u64,
}

impl Annotations {
    /// Takes one device tick. Ticks may come in any order (a repaired file); a tick whose
    /// sequence is not above the newest one is inserted in order.
    pub fn push(&mut self, sequence: u64, region: u32, probing_index: u32, phase: u32) {
        let a = Annotation {
            sequence,
            region,
            probing_index,
            phase,
        };
        if sequence > self.last_sequence {
            self.last_sequence = sequence;
            let changed = self.points.last().is_none_or(|p| {
                (p.region, p.probing_index, p.phase) != (region, probing_index, phase)
            });
            if changed {
                self.points.push(a);
            }
        } else {
            // Out of order (or a restarted device counting again): keep it as a point of its
            // own so that it and the ticks after it keep their annotation.
            let i = self.points.partition_point(|p| p.sequence < sequence);
            if self.points.get(i).is_some_and(|p| p.sequence == sequence) {
                self.points[i] = a;
            } else {
                self.points.insert(i, a);
            }
        }
    }

    /// The annotation of the device tick a step consumed; None when the step used no tick
    /// (`device_sequence_used == 0`) or one outside the ticks seen.
    pub fn of_step(&self, device_sequence_used: u64) -> Option<Annotation> {
        if device_sequence_used == 0 || device_sequence_used > self.last_sequence {
            return None;
        }
        let i = self
            .points
            .partition_point(|p| p.sequence <= device_sequence_used);
        (i > 0).then(|| self.points[i - 1])
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Number of change points kept.
    pub fn len(&self) -> usize {
        self.points.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_gets_the_annotation_of_the_tick_it_used() {
        let mut a = Annotations::default();
        for seq in 1..=300u64 {
            a.push(seq, 1 + (seq / 100) as u32, 1 + (seq / 100) as u32, 2);
        }
        assert_eq!(a.len(), 4, "change points at 1, 100, 200, 300");
        assert_eq!(a.of_step(0), None);
        assert_eq!(a.of_step(301), None);
        assert_eq!(a.of_step(99).unwrap().region, 1);
        assert_eq!(a.of_step(100).unwrap().region, 2);
        assert_eq!(a.of_step(250).unwrap().region(), Some(Region::Anterior));
    }

    #[test]
    fn out_of_order_ticks_are_placed_by_sequence() {
        let mut a = Annotations::default();
        a.push(10, 2, 2, 0);
        a.push(5, 1, 1, 0);
        assert_eq!(a.of_step(7).unwrap().region, 1);
        assert_eq!(a.of_step(10).unwrap().region, 2);
        assert_eq!(a.of_step(4), None);
    }
}
