//! Device backends behind one interface: the real Touch (OpenHaptics, loaded at run time),
//! the Touch emulator driven by an operator model, and trajectory replay. Every backend works
//! in the scene (world) frame: z up, metres, newtons; each converts at its own edge.

pub mod emulated;
pub mod operator;
pub mod replay;
pub mod touch;

use msgs::haptic_to_physics::DeviceKind;
use msgs::Pose;

/// What the device reported at one tick, in the scene frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceSample {
    pub pose: Pose,
    /// Linear m/s then angular rad/s.
    pub velocity: [f64; 6],
    /// 3 base joints + 3 gimbal angles, rad.
    pub joint_angles: [f64; 6],
    pub buttons: u32,
    /// Operator protocol annotations (0 = none): 1-based probing index, region code
    /// (1 posterior, 2 mid, 3 anterior) and phase code (see [`operator::Phase`]).
    pub probing_index: u32,
    pub region: u32,
    pub phase: u32,
}

impl Default for DeviceSample {
    fn default() -> Self {
        DeviceSample {
            pose: Pose::IDENTITY,
            velocity: [0.0; 6],
            joint_angles: [0.0; 6],
            buttons: 0,
            probing_index: 0,
            region: 0,
            phase: 0,
        }
    }
}

/// Failures of a device backend.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    #[error("OpenHaptics library {library:?} could not be loaded ({detail}); install the OpenHaptics runtime (libHD) or set [device.touch] library, or use backend = \"emulated\"")]
    LibraryMissing { library: String, detail: String },
    #[error("OpenHaptics library {library:?} lacks symbol {symbol}")]
    MissingSymbol {
        library: String,
        symbol: &'static str,
    },
    #[error("Touch device {device:?}: {detail}")]
    Touch { device: String, detail: String },
    #[error("replay file {path}: line {line}: {problem}")]
    ReplayLine {
        path: String,
        line: usize,
        problem: String,
    },
    #[error("replay file {path}: {problem}")]
    Replay { path: String, problem: String },
    #[error("emulated device: {0}")]
    Emulated(String),
}

/// One haptic device. `sample` then `command_force` once per servo tick.
pub trait Device {
    fn kind(&self) -> DeviceKind;
    /// Reads the device state at `now_ns` (CLOCK_MONOTONIC).
    fn sample(&mut self, now_ns: u64, out: &mut DeviceSample) -> Result<(), DeviceError>;
    /// Sends a force (scene frame, N), held until the next command.
    fn command_force(&mut self, now_ns: u64, force: [f64; 3]) -> Result<(), DeviceError>;
    /// Zero force now; idempotent (stop paths, drop, panic unwinding).
    fn zero_force(&mut self);
    /// The device has nothing more to do (replay or protocol ended without repeat).
    fn finished(&self) -> bool {
        false
    }
}

/// Opens the backend the `[device]` section names. `sites` are the probing sites for the
/// emulator's operator model.
pub fn open(
    config: &launch_config::DeviceConfig,
    sites: &[operator::Site],
    start_ns: u64,
) -> Result<Box<dyn Device>, DeviceError> {
    use launch_config::device::DeviceBackend;
    match config.backend {
        DeviceBackend::Touch => Ok(Box::new(touch::Touch::open(config)?)),
        DeviceBackend::Emulated => Ok(Box::new(emulated::EmulatedTouch::new(
            &config.emulated,
            operator::Protocol::new(&config.emulated, sites)?
                .with_felt_target(config.emulated.press_force_n * config.rendering().force_scale),
            start_ns,
        )?)),
        DeviceBackend::Replay => Ok(Box::new(replay::Replay::open(&config.replay, start_ns)?)),
    }
}
