//! The `[device]` section checked and converted into the numbers the servo loop uses.

use launch_config::DeviceConfig;

/// Problems with the `[device]` section.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("[device] {field} = {value}: {problem}")]
    Field {
        field: &'static str,
        value: String,
        problem: &'static str,
    },
    #[error("{0}")]
    LimitRaised(String),
    #[error("launch file {path}: {detail}")]
    Parse { path: String, detail: String },
}

/// Limits and loop settings in the units the tick uses.
#[derive(Debug, Clone, PartialEq)]
pub struct Limits {
    pub rate_hz: f64,
    pub period_ns: u64,
    /// Rendered force per tissue force (see `launch_config::device::Rendering`).
    pub force_scale: f64,
    /// Virtual coupling in series with the contact compliance, tissue side, m/N (1/k_c):
    /// bounds the felt stiffness by `force_scale / coupling_compliance_m_per_n`.
    pub coupling_compliance_m_per_n: f64,
    /// That bound, N/m.
    pub felt_stiffness_limit_n_per_m: f64,
    /// Per-axis play of the rendered stylus position, m.
    pub position_hysteresis_m: f64,
    pub peak_force_n: f64,
    pub continuous_force_n: f64,
    pub continuous_window_s: f64,
    pub max_force_rate_n_per_s: f64,
    pub stale_frame_ns: u64,
    pub stale_ramp_s: f64,
    pub lcp_max_iterations: u32,
    pub lcp_tolerance: f64,
    pub lcp_budget_ns: u64,
    pub use_rotation: bool,
    pub reference_is_probe_free: bool,
}

fn positive(field: &'static str, v: f64) -> Result<f64, ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(ConfigError::Field {
            field,
            value: v.to_string(),
            problem: "must be a finite number > 0",
        })
    }
}

impl Limits {
    pub fn from_config(c: &DeviceConfig) -> Result<Limits, ConfigError> {
        let rate_hz = positive("rate_hz", c.rate_hz)?;
        if !(10.0..=10_000.0).contains(&rate_hz) {
            return Err(ConfigError::Field {
                field: "rate_hz",
                value: rate_hz.to_string(),
                problem: "must be within 10..=10000 Hz",
            });
        }
        let window = positive("continuous_window_s", c.continuous_window_s)?;
        if window > 10.0 {
            return Err(ConfigError::Field {
                field: "continuous_window_s",
                value: window.to_string(),
                problem: "must be ≤ 10 s",
            });
        }
        let reference_is_probe_free =
            c.displacement_reference == launch_config::device::DisplacementReference::ProbeFree;
        if !(c.lcp_tolerance.is_finite() && c.lcp_tolerance >= 0.0) {
            return Err(ConfigError::Field {
                field: "lcp_tolerance",
                value: c.lcp_tolerance.to_string(),
                problem: "must be finite and ≥ 0",
            });
        }
        if c.lcp_max_iterations == 0 {
            return Err(ConfigError::Field {
                field: "lcp_max_iterations",
                value: "0".into(),
                problem: "must be ≥ 1",
            });
        }
        if !(c.force_scale.is_finite() && (0.0..=1.0).contains(&c.force_scale)) {
            return Err(ConfigError::Field {
                field: "force_scale",
                value: c.force_scale.to_string(),
                problem: "must be within 0..=1 (0 = automatic)",
            });
        }
        // The device's hard limits: checked here too, so a node started without the
        // launcher's validation cannot be given a raised limit either.
        if let Some(raise) = c.limit_raises().into_iter().next() {
            return Err(ConfigError::LimitRaised(raise.to_string()));
        }
        for (field, v) in [
            ("max_stiffness_n_per_m", c.max_stiffness_n_per_m),
            ("tissue_force_range_n", c.tissue_force_range_n),
            ("tissue_stiffness_n_per_m", c.tissue_stiffness_n_per_m),
        ] {
            positive(field, v)?;
        }
        let rendering = c.rendering();
        if !(c.stale_ramp_s.is_finite() && c.stale_ramp_s >= 0.0) {
            return Err(ConfigError::Field {
                field: "stale_ramp_s",
                value: c.stale_ramp_s.to_string(),
                problem: "must be finite and ≥ 0",
            });
        }
        Ok(Limits {
            rate_hz,
            period_ns: (1e9 / rate_hz).round() as u64,
            force_scale: rendering.force_scale,
            coupling_compliance_m_per_n: 1.0 / rendering.coupling_stiffness_n_per_m,
            felt_stiffness_limit_n_per_m: rendering.felt_stiffness_limit_n_per_m,
            position_hysteresis_m: {
                let h = c.position_hysteresis_m;
                if !(h.is_finite() && (0.0..=1e-3).contains(&h)) {
                    return Err(ConfigError::Field {
                        field: "position_hysteresis_m",
                        value: h.to_string(),
                        problem: "must be within 0..=0.001 m",
                    });
                }
                h
            },
            peak_force_n: positive("peak_force_n", c.peak_force_n)?,
            continuous_force_n: positive("continuous_force_n", c.continuous_force_n)?,
            continuous_window_s: window,
            max_force_rate_n_per_s: positive("max_force_rate_n_per_s", c.max_force_rate_n_per_s)?,
            stale_frame_ns: (positive("stale_frame_s", c.stale_frame_s)? * 1e9) as u64,
            stale_ramp_s: c.stale_ramp_s,
            lcp_max_iterations: c.lcp_max_iterations,
            lcp_tolerance: c.lcp_tolerance,
            lcp_budget_ns: (positive("lcp_budget_s", c.lcp_budget_s)? * 1e9) as u64,
            use_rotation: c.use_rotation,
            reference_is_probe_free,
        })
    }
}

/// Reads the `[device]` section of a launch file (no file: defaults), through the launch
/// helper so every node validates the file the same way.
pub fn load_device_config(path: Option<&std::path::Path>) -> Result<DeviceConfig, ConfigError> {
    let Some(path) = path else {
        return Ok(DeviceConfig::default());
    };
    let launch = launch_config::load(path).map_err(|e| ConfigError::Parse {
        path: path.display().to_string(),
        detail: e.to_string(),
    })?;
    Ok(launch.device)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_bad_values_name_the_field() {
        let l = Limits::from_config(&DeviceConfig::default()).unwrap();
        assert_eq!(l.period_ns, 1_000_000);
        assert_eq!(l.stale_frame_ns, 20_000_000);
        let c = DeviceConfig {
            peak_force_n: f64::NAN,
            ..DeviceConfig::default()
        };
        let e = Limits::from_config(&c).unwrap_err().to_string();
        assert!(e.contains("peak_force_n"), "{e}");
    }

    #[test]
    fn empty_and_partial_launch_files_parse() {
        let dir = std::env::temp_dir().join(format!("haptic-cfg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.toml");
        std::fs::write(
            dir.join("x.csv"),
            "t_s,px_m,py_m,pz_m,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n",
        )
        .unwrap();
        std::fs::write(
            &p,
            "[device]\nbackend = \"replay\"\n[device.replay]\npath = \"x.csv\"\n",
        )
        .unwrap();
        let c = load_device_config(Some(&p)).unwrap();
        assert_eq!(c.backend, launch_config::device::DeviceBackend::Replay);
        assert!(c.replay.path.ends_with("x.csv"), "{}", c.replay.path);
        assert_eq!(c.peak_force_n, 3.3);
        std::fs::write(&p, "[device]\nbogus = 1\n").unwrap();
        let e = load_device_config(Some(&p)).unwrap_err().to_string();
        assert!(e.contains("a.toml") && e.contains("bogus"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
