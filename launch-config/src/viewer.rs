//! `[viewer]`: the live viewer node (owned by the `viewer` crate). It serves the session on
//! the Foxglove WebSocket protocol (`ws_port`) and a self-contained trainee page over HTTP
//! (`http_port`), both bound to `bind`: loopback by default. A LAN address (or `0.0.0.0`)
//! is an explicit choice: everyone who can reach that address then sees the live session
//! (mesh, probe, forces, status, training prompts) and can answer a training case on the
//! page; nothing else is served and nothing can be driven.
use serde::{Deserialize, Serialize};
use std::net::IpAddr;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ViewerConfig {
    /// Start the viewer node with the session.
    pub enabled: bool,
    /// Address both servers listen on (`127.0.0.1`: this machine only).
    pub bind: String,
    /// HTTP port of the trainee page (0: any free port, printed at start).
    pub http_port: u16,
    /// Foxglove WebSocket port (0: any free port, printed at start).
    pub ws_port: u16,
    /// Rate of the mesh on both outputs, Hz.
    pub mesh_rate_hz: f64,
    /// Rate of poses, forces and status on both outputs, Hz.
    pub rate_hz: f64,
    /// Depth of the queue between the shared-memory thread and the servers; when the
    /// servers fall behind, samples are dropped and counted, never waited for.
    pub queue_depth: usize,
}

impl Default for ViewerConfig {
    fn default() -> Self {
        ViewerConfig {
            enabled: true,
            bind: "127.0.0.1".into(),
            http_port: 8080,
            ws_port: 8765,
            mesh_rate_hz: 10.0,
            rate_hz: 60.0,
            queue_depth: 64,
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ViewerConfigError {
    #[error("viewer.bind = {0:?}: not an IP address (use 127.0.0.1, or a LAN address / 0.0.0.0 to serve other machines)")]
    Bind(String),
    #[error("viewer.http_port and viewer.ws_port are both {0}: they must differ")]
    SamePort(u16),
    #[error("viewer.{key} = {value}: must be a finite rate in (0, 1000] Hz")]
    Rate { key: &'static str, value: f64 },
    #[error("viewer.queue_depth = 0: must be at least 1")]
    QueueDepth,
}

impl ViewerConfig {
    pub fn bind_addr(&self) -> Result<IpAddr, ViewerConfigError> {
        self.bind
            .parse()
            .map_err(|_| ViewerConfigError::Bind(self.bind.clone()))
    }

    /// True when the servers are reachable from other machines.
    pub fn is_lan(&self) -> bool {
        self.bind_addr().map(|a| !a.is_loopback()).unwrap_or(false)
    }

    pub fn validate(&self) -> Result<(), ViewerConfigError> {
        self.bind_addr()?;
        if self.http_port == self.ws_port && self.http_port != 0 {
            return Err(ViewerConfigError::SamePort(self.http_port));
        }
        for (key, value) in [
            ("rate_hz", self.rate_hz),
            ("mesh_rate_hz", self.mesh_rate_hz),
        ] {
            if !(value.is_finite() && value > 0.0 && value <= 1000.0) {
                return Err(ViewerConfigError::Rate { key, value });
            }
        }
        if self.queue_depth == 0 {
            return Err(ViewerConfigError::QueueDepth);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_loopback_and_valid() {
        let c = ViewerConfig::default();
        c.validate().unwrap();
        assert!(!c.is_lan());
        assert_eq!((c.http_port, c.ws_port), (8080, 8765));
    }

    #[test]
    fn bad_values_are_named() {
        let c = ViewerConfig {
            bind: "lan".into(),
            ..Default::default()
        };
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("viewer.bind"));
        let c = ViewerConfig {
            ws_port: 8080,
            ..Default::default()
        };
        assert!(c.validate().is_err());
        let c = ViewerConfig {
            bind: "0.0.0.0".into(),
            ..Default::default()
        };
        assert!(c.is_lan());
    }
}
