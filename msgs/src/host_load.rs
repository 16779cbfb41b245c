//! What the machine did while a benchmark ran: its one-minute load average and the share of
//! its CPU time the hypervisor gave to others (steal). On the VMs this project is measured
//! on, the host took from nothing to a third of the CPU within one hour (issue 15's notes),
//! and a benchmark figure without it cannot be compared with another. Linux only (`/proc`);
//! elsewhere both read as absent.

/// CPU time counters of all CPUs together, in clock ticks (`/proc/stat`'s `cpu` line).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CpuTimes {
    /// Every state, steal included.
    pub total: u64,
    /// Time the hypervisor ran something else while this VM wanted to run.
    pub steal: u64,
}

impl CpuTimes {
    /// The counters now, or None where `/proc/stat` is missing or unreadable.
    pub fn now() -> Option<CpuTimes> {
        Self::parse(&std::fs::read_to_string("/proc/stat").ok()?)
    }

    /// The aggregate `cpu` line of a `/proc/stat` text: user nice system idle iowait irq
    /// softirq steal [guest guest_nice]; guest time is already inside user and nice.
    pub fn parse(stat: &str) -> Option<CpuTimes> {
        let line = stat.lines().find(|l| l.starts_with("cpu "))?;
        let fields: Vec<u64> = line
            .split_whitespace()
            .skip(1)
            .map(|v| v.parse().ok())
            .collect::<Option<_>>()?;
        if fields.len() < 8 {
            return None;
        }
        Some(CpuTimes {
            total: fields[..8].iter().sum(),
            steal: fields[7],
        })
    }

    /// Share of the CPU time since `earlier` that was stolen (0…1); None without time passed.
    pub fn steal_fraction_since(&self, earlier: &CpuTimes) -> Option<f64> {
        let total = self.total.checked_sub(earlier.total)?;
        let steal = self.steal.checked_sub(earlier.steal)?;
        (total > 0).then(|| steal as f64 / total as f64)
    }
}

/// The one-minute load average, or None where `/proc/loadavg` is missing or unreadable.
pub fn loadavg_1m() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// The machine over one measurement: load before and after, and the steal share between.
#[derive(Debug, Clone, Copy)]
pub struct HostLoad {
    loadavg_before: Option<f64>,
    cpu_before: Option<CpuTimes>,
}

impl HostLoad {
    /// Takes the "before" sample.
    pub fn start() -> HostLoad {
        HostLoad {
            loadavg_before: loadavg_1m(),
            cpu_before: CpuTimes::now(),
        }
    }

    /// The "after" sample and the figures between.
    pub fn finish(&self) -> HostFigures {
        let host_steal_fraction = match (self.cpu_before, CpuTimes::now()) {
            (Some(a), Some(b)) => b.steal_fraction_since(&a),
            _ => None,
        };
        HostFigures {
            loadavg_1m_before: self.loadavg_before,
            loadavg_1m_after: loadavg_1m(),
            host_steal_fraction,
        }
    }
}

/// The fields a benchmark's JSON line carries about the machine (null where not readable).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HostFigures {
    pub loadavg_1m_before: Option<f64>,
    pub loadavg_1m_after: Option<f64>,
    pub host_steal_fraction: Option<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steal_is_the_eighth_field_of_the_cpu_line() {
        let a = CpuTimes::parse(
            "cpu  2216404 1543031 155408 617915 12014 0 3060 99865 0 0\ncpu0 1 2 3 4 5 6 7 8 0 0\n",
        )
        .unwrap();
        let b = CpuTimes::parse("cpu  2216759 1543031 155514 619209 12018 0 3062 100631 0 0\n")
            .unwrap();
        // 355 + 106 + 1294 + 4 + 2 + 766 ticks, 766 of them stolen
        let f = b.steal_fraction_since(&a).unwrap();
        assert!((f - 766.0 / 2527.0).abs() < 1e-12, "{f}");
        assert_eq!(a.steal_fraction_since(&a), None);
        assert_eq!(a.steal_fraction_since(&b), None, "counters going back");
    }

    #[test]
    fn a_malformed_stat_is_absent_not_a_panic() {
        assert_eq!(CpuTimes::parse(""), None);
        assert_eq!(CpuTimes::parse("cpu  1 2 3"), None);
        assert_eq!(CpuTimes::parse("cpu  1 2 x 4 5 6 7 8"), None);
        assert_eq!(CpuTimes::parse("cpu0 1 2 3 4 5 6 7 8"), None);
    }
}
