//! Live status of a running session, read over iceoryx2 like any other subscriber: every
//! physics step (ContactFrame, `Queue::Every`), every device state (for the protocol's
//! region and probing annotations) and the haptic node's own statistics.
//!
//! The ports are not `Send`: create the [`StatusMonitor`] on the thread that polls it.

use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc::{self, IpcNode, IpcSubscriber, LinkError, Queue};
use msgs::physics_to_haptic::ContactFrame;
use session_metrics::summary::SessionRecord;
use std::fmt;

/// What the live status line shows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LiveStatus {
    /// Physics steps per second over the last poll window.
    pub physics_hz: Option<f64>,
    /// Haptic ticks per second (the node's own estimate when published, else received rate).
    pub haptic_hz: Option<f64>,
    /// Contact force magnitude of the newest physics step, N.
    pub contact_force_n: Option<f64>,
    pub contact_count: u32,
    /// Age of the contact frame the haptic loop used (its p50), else of the newest frame, ms.
    pub frame_age_ms: Option<f64>,
    /// Region code of the newest device state.
    pub region: u32,
    pub probing_index: u32,
}

impl fmt::Display for LiveStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let num = |v: Option<f64>, d: usize| v.map_or("–".to_string(), |x| format!("{x:.d$}"));
        let region = msgs::protocol::Region::name_of_code(self.region);
        write!(
            f,
            "physics {} Hz | haptic {} Hz | contact {} N ({}) | frame age {} ms | {} #{}",
            num(self.physics_hz, 0),
            num(self.haptic_hz, 0),
            num(self.contact_force_n, 2),
            self.contact_count,
            num(self.frame_age_ms, 2),
            if self.region == 0 { "–" } else { region },
            self.probing_index
        )
    }
}

/// The launcher's subscriber set for one session.
pub struct StatusMonitor {
    _node: IpcNode,
    frames: IpcSubscriber<ContactFrame>,
    devices: IpcSubscriber<DeviceState>,
    stats: IpcSubscriber<HapticStats>,
    window_start_ns: u64,
    window_frames: u64,
    window_ticks: u64,
    status: LiveStatus,
    newest_frame_ns: u64,
    /// Samples lost because the launcher fell behind (queue overflow shows as sequence gaps).
    pub frames_missed: u64,
    last_frame: Option<(u64, u64)>,
}

impl StatusMonitor {
    pub fn new(session: &str) -> Result<StatusMonitor, LinkError> {
        let node = ipc::create_node(&format!("launcher-{}", std::process::id()))?;
        let frames = ipc::subscriber::<ContactFrame>(&node, session, Queue::Every)?;
        let devices = ipc::subscriber::<DeviceState>(&node, session, Queue::Every)?;
        let stats = ipc::subscriber::<HapticStats>(&node, session, Queue::Newest)?;
        Ok(StatusMonitor {
            _node: node,
            frames,
            devices,
            stats,
            window_start_ns: msgs::clock::monotonic_ns(),
            window_frames: 0,
            window_ticks: 0,
            status: LiveStatus::default(),
            newest_frame_ns: 0,
            frames_missed: 0,
            last_frame: None,
        })
    }

    /// Drains every queue into `record` and updates the live status. Call at least every
    /// second: the device queue holds about two seconds of 1 kHz ticks.
    pub fn poll(&mut self, record: &mut SessionRecord) -> Result<&LiveStatus, LinkError> {
        let mut newest_force = None;
        let mut contact_count = self.status.contact_count;
        let mut frames = 0;
        let mut missed = 0;
        let mut last = self.last_frame;
        let mut newest_ns = self.newest_frame_ns;
        ipc::drain_each(&self.frames, |frame: &ContactFrame| {
            if let Some((instance, seq)) = last {
                if instance == frame.instance_id && frame.sequence > seq + 1 {
                    missed += frame.sequence - seq - 1;
                }
            }
            last = Some((frame.instance_id, frame.sequence));
            record.push_contact(frame);
            let f = frame.contact_force;
            newest_force = Some((f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt());
            contact_count = frame.contact_count;
            newest_ns = frame.publish_ns;
            frames += 1;
        })?;
        self.last_frame = last;
        self.frames_missed += missed;
        self.newest_frame_ns = newest_ns;
        let mut ticks = 0;
        let mut region = self.status.region;
        let mut probing = self.status.probing_index;
        ipc::drain_each(&self.devices, |d: &DeviceState| {
            record.push_device(
                d.instance_id,
                d.sequence,
                d.publish_ns,
                d.region,
                d.probing_index,
                d.phase,
            );
            region = d.region;
            probing = d.probing_index;
            ticks += 1;
        })?;
        let mut stats = None;
        ipc::drain_each(&self.stats, |s: &HapticStats| stats = Some(*s))?;

        self.window_frames += frames;
        self.window_ticks += ticks;
        let now = msgs::clock::monotonic_ns();
        let elapsed = now.saturating_sub(self.window_start_ns) as f64 * 1e-9;
        if elapsed >= 0.5 {
            self.status.physics_hz = Some(self.window_frames as f64 / elapsed);
            let received = self.window_ticks as f64 / elapsed;
            self.status.haptic_hz = Some(received);
            self.window_start_ns = now;
            self.window_frames = 0;
            self.window_ticks = 0;
        }
        if let Some(f) = newest_force {
            self.status.contact_force_n = Some(f);
        }
        self.status.contact_count = contact_count;
        self.status.region = region;
        self.status.probing_index = probing;
        if let Some(s) = stats {
            if s.tick_hz.is_finite() && s.tick_hz > 0.0 {
                self.status.haptic_hz = Some(s.tick_hz);
                record.haptic_reported_hz = Some(s.tick_hz);
            }
            if s.frame_age_p50_us.is_finite() && s.frame_age_p50_us > 0.0 {
                self.status.frame_age_ms = Some(s.frame_age_p50_us * 1e-3);
            }
        } else if self.newest_frame_ns > 0 {
            self.status.frame_age_ms = Some(now.saturating_sub(self.newest_frame_ns) as f64 * 1e-6);
        }
        Ok(&self.status)
    }

    pub fn status(&self) -> &LiveStatus {
        &self.status
    }
}
