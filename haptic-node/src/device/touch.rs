//! The 3D Systems Touch through the OpenHaptics HD API, loaded at run time with `dlopen`, so
//! the project builds and tests on machines without the runtime or the device.
//!
//! The HD scheduler runs its own 1 kHz servo thread; an asynchronous callback exchanges data
//! with the node loop through a small mutex-protected state (try-lock on the servo side, so
//! it never blocks). The callback applies the newest force from the node loop, and ramps it
//! to zero on its own when the node loop stops updating it (servo watchdog). Zero force is
//! written on every exit path: `zero_force`, `Drop` (also during panic unwinding), and the
//! callback itself once stopping is requested.
//!
//! Device frame (OpenHaptics): mm, x right, y up, z toward the user. Scene frame: m, z up:
//! x_s = x_d, y_s = −z_d, z_s = y_d, then `workspace_scale` and `workspace_offset_m`.

use super::{Device, DeviceError, DeviceSample};
use launch_config::DeviceConfig;
use msgs::haptic_to_physics::DeviceKind;
use msgs::Pose;
use std::ffi::{c_char, c_int, c_uint, c_ulong, c_ushort, c_void, CStr, CString};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

type Hhd = c_uint;
type HdEnum = c_uint;
type HdCallbackCode = c_uint;
type HdSchedulerHandle = c_ulong;
type SchedulerCallback = unsafe extern "C" fn(*mut c_void) -> HdCallbackCode;

const HD_INVALID_HANDLE: Hhd = 0xFFFF_FFFF;
const HD_SUCCESS: c_uint = 0x0000;
const HD_CURRENT_BUTTONS: HdEnum = 0x2000;
const HD_CURRENT_POSITION: HdEnum = 0x2050;
const HD_CURRENT_VELOCITY: HdEnum = 0x2051;
const HD_CURRENT_TRANSFORM: HdEnum = 0x2052;
const HD_CURRENT_JOINT_ANGLES: HdEnum = 0x2100;
const HD_CURRENT_GIMBAL_ANGLES: HdEnum = 0x2150;
const HD_CALIBRATION_STYLE: HdEnum = 0x2650;
const HD_CURRENT_FORCE: HdEnum = 0x2700;
const HD_FORCE_OUTPUT: HdEnum = 0x4000;
const HD_CALIBRATION_OK: HdEnum = 0x5000;
const HD_CALIBRATION_NEEDS_UPDATE: HdEnum = 0x5001;
const HD_CALIBRATION_NEEDS_MANUAL_INPUT: HdEnum = 0x5002;
const HD_CALIBRATION_AUTO: c_int = 1 << 1;
const HD_CALIBRATION_INKWELL: c_int = 1 << 2;
const HD_CALLBACK_DONE: HdCallbackCode = 0;
const HD_CALLBACK_CONTINUE: HdCallbackCode = 1;
// The servo callback runs first in each scheduler tick, as in the OpenHaptics examples.
const HD_MAX_SCHEDULER_PRIORITY: c_ushort = 0xffff;

#[repr(C)]
#[derive(Debug, Clone, Copy)]
struct HdErrorInfo {
    error_code: c_uint,
    internal_error_code: c_int,
    hhd: Hhd,
}

/// The HD API entry points the node uses.
struct HdApi {
    handle: *mut c_void,
    init_device: unsafe extern "C" fn(*const c_char) -> Hhd,
    disable_device: unsafe extern "C" fn(Hhd),
    make_current_device: unsafe extern "C" fn(Hhd),
    get_error: unsafe extern "C" fn() -> HdErrorInfo,
    get_error_string: unsafe extern "C" fn(c_uint) -> *const c_char,
    enable: unsafe extern "C" fn(HdEnum),
    start_scheduler: unsafe extern "C" fn(),
    stop_scheduler: unsafe extern "C" fn(),
    schedule_asynchronous:
        unsafe extern "C" fn(SchedulerCallback, *mut c_void, c_ushort) -> HdSchedulerHandle,
    unschedule: unsafe extern "C" fn(HdSchedulerHandle),
    begin_frame: unsafe extern "C" fn(Hhd),
    end_frame: unsafe extern "C" fn(Hhd),
    get_doublev: unsafe extern "C" fn(HdEnum, *mut f64),
    get_integerv: unsafe extern "C" fn(HdEnum, *mut c_int),
    set_doublev: unsafe extern "C" fn(HdEnum, *const f64),
    check_calibration: unsafe extern "C" fn() -> HdEnum,
    update_calibration: unsafe extern "C" fn(c_int),
}

impl HdApi {
    fn load(library: &str) -> Result<HdApi, DeviceError> {
        let name = CString::new(library).map_err(|_| DeviceError::LibraryMissing {
            library: library.into(),
            detail: "name contains a NUL byte".into(),
        })?;
        // SAFETY: dlopen with a valid C string; the handle is checked.
        let handle = unsafe { libc::dlopen(name.as_ptr(), libc::RTLD_NOW | libc::RTLD_LOCAL) };
        if handle.is_null() {
            // SAFETY: dlerror returns a thread-local C string or null.
            let detail = unsafe {
                let e = libc::dlerror();
                if e.is_null() {
                    "unknown dlopen error".to_string()
                } else {
                    CStr::from_ptr(e).to_string_lossy().into_owned()
                }
            };
            return Err(DeviceError::LibraryMissing {
                library: library.into(),
                detail,
            });
        }
        macro_rules! sym {
            ($name:literal) => {{
                let c = concat!($name, "\0");
                // SAFETY: handle is a live dlopen handle, the name is NUL-terminated.
                let p = unsafe { libc::dlsym(handle, c.as_ptr() as *const c_char) };
                if p.is_null() {
                    // SAFETY: closing the handle we opened.
                    unsafe { libc::dlclose(handle) };
                    return Err(DeviceError::MissingSymbol {
                        library: library.into(),
                        symbol: $name,
                    });
                }
                // The target type is the field's: one macro for every HD function.
                #[allow(clippy::missing_transmute_annotations)]
                // SAFETY: the symbol has the HD API signature of the field it is stored in.
                let f = unsafe { std::mem::transmute::<*mut c_void, _>(p) };
                f
            }};
        }
        Ok(HdApi {
            handle,
            init_device: sym!("hdInitDevice"),
            disable_device: sym!("hdDisableDevice"),
            make_current_device: sym!("hdMakeCurrentDevice"),
            get_error: sym!("hdGetError"),
            get_error_string: sym!("hdGetErrorString"),
            enable: sym!("hdEnable"),
            start_scheduler: sym!("hdStartScheduler"),
            stop_scheduler: sym!("hdStopScheduler"),
            schedule_asynchronous: sym!("hdScheduleAsynchronous"),
            unschedule: sym!("hdUnschedule"),
            begin_frame: sym!("hdBeginFrame"),
            end_frame: sym!("hdEndFrame"),
            get_doublev: sym!("hdGetDoublev"),
            get_integerv: sym!("hdGetIntegerv"),
            set_doublev: sym!("hdSetDoublev"),
            check_calibration: sym!("hdCheckCalibration"),
            update_calibration: sym!("hdUpdateCalibration"),
        })
    }

    /// Pops the pending HD error, if any (no allocation: used in the servo callback).
    fn pending_error(&self) -> Option<HdErrorInfo> {
        // SAFETY: plain HD API call on a loaded library.
        let e = unsafe { (self.get_error)() };
        (e.error_code != HD_SUCCESS).then_some(e)
    }

    /// An HD error as text.
    fn describe(&self, e: HdErrorInfo) -> String {
        // SAFETY: plain HD API call; the string is static in the library, or null.
        let text = unsafe {
            let s = (self.get_error_string)(e.error_code);
            if s.is_null() {
                String::new()
            } else {
                CStr::from_ptr(s).to_string_lossy().into_owned()
            }
        };
        format!(
            "HD error 0x{:04x} ({text}), internal {}",
            e.error_code, e.internal_error_code
        )
    }

    /// The pending HD error, if any, as text.
    fn error(&self) -> Option<String> {
        self.pending_error().map(|e| self.describe(e))
    }
}

impl Drop for HdApi {
    fn drop(&mut self) {
        // SAFETY: closing the handle opened in `load`.
        unsafe { libc::dlclose(self.handle) };
    }
}

/// How long the servo callback holds zero force after an HD error (lost communication, a
/// force or velocity limit, overheating). The node loop sees a device error meanwhile and
/// afterwards ramps the force back in under its rate limit.
pub const HD_FAULT_HOLD_NS: u64 = 500_000_000;

/// Exchanged between the node loop and the servo callback.
#[derive(Debug, Clone, Copy, Default)]
struct ServoState {
    position_mm: [f64; 3],
    velocity_mm_s: [f64; 3],
    transform: [f64; 16],
    joints: [f64; 3],
    gimbal: [f64; 3],
    buttons: c_int,
    /// Force to apply, device frame, N, and when the node loop set it.
    force: [f64; 3],
    force_set_ns: u64,
    /// Force actually written on the last servo tick.
    applied: [f64; 3],
    servo_ticks: u64,
    /// Zero force until this time after an HD error; the newest error and how many there were.
    fault_until_ns: u64,
    last_error: Option<HdErrorInfo>,
    errors: u64,
    /// Servo ticks that found this state locked (they held the last command).
    contended: u64,
}

/// The servo callback's own copy of the node loop's command and what it wrote last. Only
/// the servo thread touches it, so its lock is never contended; it lets a tick whose
/// try-lock on the shared state fails keep rendering the last command (under the watchdog)
/// instead of dropping to zero for a millisecond and back, a jump no rate limit allows.
#[derive(Debug, Clone, Copy, Default)]
struct ServoOwn {
    /// Last command seen (device frame, N) and when the node loop set it.
    command: [f64; 3],
    command_set_ns: u64,
    /// Force written on the last servo tick, and when.
    written: [f64; 3],
    written_ns: Option<u64>,
    /// Ticks on which the shared state was contended.
    contended: u64,
}

/// The callback's own clamp, independent of the node loop's limiter: never above the peak,
/// never rising faster than the rate limit allows for the time since the last write (a
/// late callback does not license a bigger step; falling is always allowed).
#[derive(Debug, Clone, Copy)]
struct ServoClamp {
    peak_n: f64,
    rate_n_per_ns: f64,
    /// Largest elapsed time credited to one step (two servo periods), ns.
    max_elapsed_ns: u64,
}

impl ServoClamp {
    fn apply(&self, f: [f64; 3], last: [f64; 3], elapsed_ns: Option<u64>) -> [f64; 3] {
        let n = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        let f = if n > self.peak_n {
            f.map(|v| v * (self.peak_n / n) * (1.0 - 4.0 * f64::EPSILON))
        } else {
            f
        };
        let step = [f[0] - last[0], f[1] - last[1], f[2] - last[2]];
        let sn = (step[0] * step[0] + step[1] * step[1] + step[2] * step[2]).sqrt();
        let ln = (last[0] * last[0] + last[1] * last[1] + last[2] * last[2]).sqrt();
        let fnorm = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        let max_step = self.rate_n_per_ns
            * elapsed_ns
                .unwrap_or(self.max_elapsed_ns)
                .min(self.max_elapsed_ns) as f64;
        // Toward zero (fades, faults, stop) is never limited; anything else is.
        if sn > max_step && !(fnorm <= ln && f.iter().zip(&last).all(|(a, b)| a * b >= 0.0)) {
            let s = max_step / sn;
            [
                last[0] + step[0] * s,
                last[1] + step[1] * s,
                last[2] + step[2] * s,
            ]
        } else {
            f
        }
    }
}

struct Servo {
    api: HdApi,
    hhd: Hhd,
    state: Mutex<ServoState>,
    stopping: AtomicBool,
    watchdog_ns: u64,
    clamp: ServoClamp,
    /// Written only by the servo thread: the fault hold survives a missed try-lock.
    fault: Mutex<(u64, Option<HdErrorInfo>, u64)>,
    own: Mutex<ServoOwn>,
}

unsafe extern "C" fn servo_callback(user: *mut c_void) -> HdCallbackCode {
    // Never unwind into C.
    let r = std::panic::catch_unwind(|| {
        // SAFETY: `user` is the Servo boxed by Touch, alive until the callback is unscheduled.
        let servo = unsafe { &*(user as *const Servo) };
        servo.tick()
    });
    r.unwrap_or(HD_CALLBACK_DONE)
}

impl Servo {
    /// Latches an HD error: zero force for [`HD_FAULT_HOLD_NS`] from `now`.
    fn latch(&self, now: u64, e: HdErrorInfo) {
        if let Ok(mut f) = self.fault.try_lock() {
            f.0 = now + HD_FAULT_HOLD_NS;
            f.1 = Some(e);
            f.2 += 1;
        }
    }

    fn tick(&self) -> HdCallbackCode {
        let api = &self.api;
        let mut s = ServoState::default();
        // SAFETY: HD API calls inside a frame on the scheduler thread, pointers to locals.
        unsafe {
            (api.begin_frame)(self.hhd);
            (api.get_doublev)(HD_CURRENT_POSITION, s.position_mm.as_mut_ptr());
            (api.get_doublev)(HD_CURRENT_VELOCITY, s.velocity_mm_s.as_mut_ptr());
            (api.get_doublev)(HD_CURRENT_TRANSFORM, s.transform.as_mut_ptr());
            (api.get_doublev)(HD_CURRENT_JOINT_ANGLES, s.joints.as_mut_ptr());
            (api.get_doublev)(HD_CURRENT_GIMBAL_ANGLES, s.gimbal.as_mut_ptr());
            (api.get_integerv)(HD_CURRENT_BUTTONS, &mut s.buttons);
        }
        let now = msgs::clock::monotonic_ns();
        // An error raised since the last tick (its force write, or this frame's reads).
        if let Some(e) = api.pending_error() {
            self.latch(now, e);
        }
        let (fault_until_ns, last_error, errors) =
            self.fault
                .try_lock()
                .map(|f| *f)
                .unwrap_or((u64::MAX, None, 0));
        let faulted = now < fault_until_ns;
        let stopping = self.stopping.load(Ordering::SeqCst);
        // The servo thread's own state: never contended (only this thread locks it).
        let mut own_guard = self.own.try_lock();
        let mut own = own_guard.as_deref().copied().unwrap_or_default();
        let shared = self.state.try_lock();
        match &shared {
            Ok(shared) => {
                own.command = shared.force;
                own.command_set_ns = shared.force_set_ns;
            }
            // Contended: the last command seen stands (the watchdog still ages it).
            Err(_) => own.contended += 1,
        }
        let mut force = [0.0; 3];
        if !stopping && !faulted && own.command.iter().all(|v| v.is_finite()) {
            // Watchdog: a stalled node loop fades the force out over one more watchdog time.
            let age = now.saturating_sub(own.command_set_ns);
            let fade = if age <= self.watchdog_ns {
                1.0
            } else {
                (2.0 - age as f64 / self.watchdog_ns as f64).clamp(0.0, 1.0)
            };
            force = own.command.map(|f| f * fade);
        }
        if own_guard.is_err() {
            // Cannot happen (one thread); without the last write, the clamp allows no rise.
            force = [0.0; 3];
        }
        let elapsed = own.written_ns.map(|t| now.saturating_sub(t));
        force = self.clamp.apply(force, own.written, elapsed);
        own.written = force;
        own.written_ns = Some(now);
        if let Ok(g) = own_guard.as_deref_mut() {
            *g = own;
        }
        if let Ok(mut shared) = shared {
            s.force = shared.force;
            s.force_set_ns = shared.force_set_ns;
            s.servo_ticks = shared.servo_ticks + 1;
            s.applied = force;
            s.fault_until_ns = fault_until_ns;
            s.last_error = last_error;
            s.errors = errors;
            s.contended = own.contended;
            *shared = s;
        }
        // SAFETY: as above.
        unsafe {
            (api.set_doublev)(HD_CURRENT_FORCE, force.as_ptr());
            (api.end_frame)(self.hhd);
        }
        if let Some(e) = api.pending_error() {
            self.latch(now, e);
        }
        if stopping {
            HD_CALLBACK_DONE
        } else {
            HD_CALLBACK_CONTINUE
        }
    }
}

impl ServoClamp {
    /// The configured peak and rate, each at most the Touch's hard limit whatever the
    /// configuration says (a node started without validation included).
    fn for_config(config: &DeviceConfig) -> ServoClamp {
        let hard = &launch_config::device::TOUCH_LIMITS;
        let pick = |v: f64, limit: f64| {
            if v.is_finite() && v > 0.0 {
                v.min(limit)
            } else {
                limit
            }
        };
        ServoClamp {
            peak_n: pick(config.peak_force_n, hard.peak_force_n),
            rate_n_per_ns: pick(config.max_force_rate_n_per_s, hard.max_force_rate_n_per_s) * 1e-9,
            max_elapsed_ns: 2_000_000,
        }
    }
}

pub struct Touch {
    servo: Box<Servo>,
    scheduler: HdSchedulerHandle,
    device_name: String,
    scale: f64,
    offset: [f64; 3],
    zeroed: bool,
}

fn device_to_scene(d: [f64; 3]) -> [f64; 3] {
    [d[0], -d[2], d[1]]
}

fn scene_to_device(s: [f64; 3]) -> [f64; 3] {
    [s[0], s[2], -s[1]]
}

/// Unit quaternion [x, y, z, w] of a rotation matrix given row-major as m[r][c].
pub fn quaternion_from_matrix(m: [[f64; 3]; 3]) -> [f64; 4] {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
            0.25 * s,
        ]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        [
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[2][1] - m[1][2]) / s,
        ]
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        [
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
            (m[0][2] - m[2][0]) / s,
        ]
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        [
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
            (m[1][0] - m[0][1]) / s,
        ]
    };
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| v / n)
}

impl Touch {
    /// Loads libHD, initialises the device, checks (and if allowed updates) calibration,
    /// enables force output and starts the servo callback.
    pub fn open(config: &DeviceConfig) -> Result<Touch, DeviceError> {
        let c = &config.touch;
        let api = HdApi::load(&c.library)?;
        let name = CString::new(c.device_name.clone()).map_err(|_| DeviceError::Touch {
            device: c.device_name.clone(),
            detail: "device name contains a NUL byte".into(),
        })?;
        let touch_err = |detail: String| DeviceError::Touch {
            device: c.device_name.clone(),
            detail,
        };
        // SAFETY: HD API calls in the documented order on the loaded library.
        let hhd = unsafe { (api.init_device)(name.as_ptr()) };
        if hhd == HD_INVALID_HANDLE {
            return Err(touch_err(format!(
                "cannot initialise: {} (is it connected and configured with Touch_Setup?)",
                api.error().unwrap_or_else(|| "no error reported".into())
            )));
        }
        // SAFETY: as above, with a valid handle.
        unsafe {
            (api.make_current_device)(hhd);
            match (api.check_calibration)() {
                HD_CALIBRATION_OK => {}
                HD_CALIBRATION_NEEDS_UPDATE if c.auto_calibrate => {
                    let mut styles: c_int = 0;
                    (api.get_integerv)(HD_CALIBRATION_STYLE, &mut styles);
                    let style = if styles & HD_CALIBRATION_AUTO != 0 {
                        HD_CALIBRATION_AUTO
                    } else {
                        HD_CALIBRATION_INKWELL
                    };
                    (api.update_calibration)(style);
                    tracing::info!("Touch calibration updated");
                }
                HD_CALIBRATION_NEEDS_UPDATE => {
                    (api.disable_device)(hhd);
                    return Err(touch_err(
                        "calibration needs an update and auto_calibrate is off".into(),
                    ));
                }
                HD_CALIBRATION_NEEDS_MANUAL_INPUT => {
                    (api.disable_device)(hhd);
                    return Err(touch_err(
                        "calibration needs manual input: put the stylus in the inkwell".into(),
                    ));
                }
                other => tracing::warn!("unexpected calibration status 0x{other:04x}"),
            }
            (api.enable)(HD_FORCE_OUTPUT);
        }
        let servo = Box::new(Servo {
            api,
            hhd,
            state: Mutex::new(ServoState::default()),
            stopping: AtomicBool::new(false),
            fault: Mutex::new((0, None, 0)),
            own: Mutex::new(ServoOwn::default()),
            watchdog_ns: (c.servo_watchdog_s.clamp(
                launch_config::device::SERVO_WATCHDOG_RANGE_S.0,
                launch_config::device::SERVO_WATCHDOG_RANGE_S.1,
            ) * 1e9) as u64,
            clamp: ServoClamp::for_config(config),
        });
        let user = &*servo as *const Servo as *mut c_void;
        // SAFETY: the Servo box outlives the scheduled callback (unscheduled in Drop).
        let scheduler = unsafe {
            let h =
                (servo.api.schedule_asynchronous)(servo_callback, user, HD_MAX_SCHEDULER_PRIORITY);
            (servo.api.start_scheduler)();
            h
        };
        if let Some(e) = servo.api.error() {
            // SAFETY: tearing down what was started.
            unsafe {
                (servo.api.unschedule)(scheduler);
                (servo.api.stop_scheduler)();
                (servo.api.disable_device)(hhd);
            }
            return Err(touch_err(format!("cannot start the servo scheduler: {e}")));
        }
        tracing::info!(device = %c.device_name, "Touch open, servo callback at 1 kHz");
        Ok(Touch {
            servo,
            scheduler,
            device_name: c.device_name.clone(),
            scale: config.workspace_scale,
            offset: config.workspace_offset_m,
            zeroed: false,
        })
    }
}

impl Touch {
    /// Holds the node side's lock on the shared servo state for `d` (tests: forced
    /// contention; the servo callback must keep the last command meanwhile).
    #[doc(hidden)]
    pub fn hold_shared_state_for(&self, d: std::time::Duration) {
        let _g = self.servo.state.lock().unwrap_or_else(|p| p.into_inner());
        std::thread::sleep(d);
    }

    /// Servo ticks so far that found the shared state contended.
    pub fn contended_ticks(&self) -> u64 {
        self.servo
            .state
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .contended
    }
}

impl Device for Touch {
    fn kind(&self) -> DeviceKind {
        DeviceKind::Touch
    }

    fn sample(&mut self, now_ns: u64, out: &mut DeviceSample) -> Result<(), DeviceError> {
        let s = *self.servo.state.lock().unwrap_or_else(|p| p.into_inner());
        if now_ns < s.fault_until_ns {
            let what = s
                .last_error
                .map(|e| self.servo.api.describe(e))
                .unwrap_or_else(|| "HD error".into());
            return Err(DeviceError::Touch {
                device: self.device_name.clone(),
                detail: format!(
                    "the servo loop reported {what} ({} so far); zero force for {} ms",
                    s.errors,
                    HD_FAULT_HOLD_NS / 1_000_000
                ),
            });
        }
        let p = device_to_scene(s.position_mm);
        let v = device_to_scene(s.velocity_mm_s);
        for k in 0..3 {
            out.pose.position[k] = self.offset[k] + self.scale * p[k] * 1e-3;
            out.velocity[k] = self.scale * v[k] * 1e-3;
        }
        // HD transform: column-major 4×4; rotation part R_d, scene rotation M·R_d.
        let t = s.transform;
        let rd = [[t[0], t[4], t[8]], [t[1], t[5], t[9]], [t[2], t[6], t[10]]];
        let m = [rd[0], [-rd[2][0], -rd[2][1], -rd[2][2]], rd[1]];
        out.pose.orientation = if rd.iter().flatten().all(|v| *v == 0.0) {
            Pose::IDENTITY.orientation
        } else {
            quaternion_from_matrix(m)
        };
        out.velocity[3..].fill(0.0);
        out.joint_angles = [
            s.joints[0],
            s.joints[1],
            s.joints[2],
            s.gimbal[0],
            s.gimbal[1],
            s.gimbal[2],
        ];
        out.buttons = s.buttons as u32;
        Ok(())
    }

    fn command_force(&mut self, now_ns: u64, force: [f64; 3]) -> Result<(), DeviceError> {
        let f = if force.iter().all(|v| v.is_finite()) {
            force
        } else {
            [0.0; 3]
        };
        let mut s = self.servo.state.lock().unwrap_or_else(|p| p.into_inner());
        s.force = scene_to_device(f);
        s.force_set_ns = now_ns;
        self.zeroed = false;
        Ok(())
    }

    fn zero_force(&mut self) {
        let mut s = self.servo.state.lock().unwrap_or_else(|p| p.into_inner());
        s.force = [0.0; 3];
        s.force_set_ns = msgs::clock::monotonic_ns();
        self.zeroed = true;
    }
}

impl Drop for Touch {
    fn drop(&mut self) {
        self.zero_force();
        self.servo.stopping.store(true, Ordering::SeqCst);
        let api = &self.servo.api;
        // SAFETY: stop the scheduler (the callback has written zero force), then write zero
        // once more from this thread and release the device.
        unsafe {
            (api.stop_scheduler)();
            (api.unschedule)(self.scheduler);
            (api.make_current_device)(self.servo.hhd);
            (api.begin_frame)(self.servo.hhd);
            (api.set_doublev)(HD_CURRENT_FORCE, [0.0f64; 3].as_ptr());
            (api.end_frame)(self.servo.hhd);
            (api.disable_device)(self.servo.hhd);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_library_is_a_clear_error() {
        let mut c = DeviceConfig {
            backend: launch_config::device::DeviceBackend::Touch,
            ..Default::default()
        };
        c.touch.library = "libHD-not-installed-here.so".into();
        let e = match Touch::open(&c) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("no libHD here"),
        };
        assert!(
            e.contains("libHD-not-installed-here.so") && e.contains("emulated"),
            "{e}"
        );
    }

    #[test]
    fn library_without_hd_symbols_is_rejected_by_name() {
        // libc is loadable but is not OpenHaptics.
        let mut c = DeviceConfig::default();
        c.touch.library = "libc.so.6".into();
        let e = match Touch::open(&c) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("libc is not libHD"),
        };
        assert!(e.contains("hdInitDevice"), "{e}");
    }

    #[test]
    fn frames_convert_as_a_proper_rotation() {
        let d = [1.0, 2.0, 3.0];
        assert_eq!(device_to_scene(d), [1.0, -3.0, 2.0]);
        assert_eq!(scene_to_device(device_to_scene(d)), d);
        let q = quaternion_from_matrix([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]);
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!((q[0] - h).abs() < 1e-12 && (q[3] - h).abs() < 1e-12);
    }
}
