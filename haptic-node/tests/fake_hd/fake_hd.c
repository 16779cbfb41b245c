/*
 * A stand-in for OpenHaptics libHD: the subset of the HD API the haptic node loads, with a
 * simulated stylus and a 1 kHz scheduler thread, so the `touch` backend's load, calibration,
 * scheduler callback, frames, force output and shutdown run end to end without the runtime
 * or a device. It also checks the caller: force writes outside a frame, unbalanced frames,
 * force output never enabled, the device not disabled.
 *
 * Set by environment variables (read at hdInitDevice):
 *   FAKE_HD_POSITION_MM  "x,y,z"  stylus position, device frame, mm (default 0,0,0)
 *   FAKE_HD_CALIBRATION  ok | update | manual  what hdCheckCalibration answers
 *   FAKE_HD_INIT         fail  hdInitDevice fails with a communication error
 *   FAKE_HD_ERROR_AT_MS  N  the servo frame N ms after the scheduler starts raises an error
 *   FAKE_HD_NAN_AT_MS    N  from N ms after the scheduler starts the position reads NaN
 *   FAKE_HD_REPORT       path  written by hdDisableDevice: key value lines and every force
 *                        write as "force t_ms fx fy fz" (device frame, N)
 * A test that loads the library into its own process sets the report path with
 * fake_hd_set_report instead (its environment is shared with concurrent tests).
 */
#define _GNU_SOURCE
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef unsigned int HHD;
typedef unsigned int HDenum;
typedef unsigned int HDCallbackCode;
typedef unsigned long HDSchedulerHandle;
typedef HDCallbackCode (*HDSchedulerCallback)(void *);
typedef struct {
    unsigned int errorCode;
    int internalErrorCode;
    HHD hHD;
} HDErrorInfo;

#define HD_INVALID_HANDLE 0xFFFFFFFFu
#define HD_SUCCESS 0x0000
#define HD_COMM_ERROR 0x0201
#define HD_ILLEGAL_BEGIN 0x0204
#define HD_CURRENT_BUTTONS 0x2000
#define HD_CURRENT_POSITION 0x2050
#define HD_CURRENT_VELOCITY 0x2051
#define HD_CURRENT_TRANSFORM 0x2052
#define HD_CURRENT_JOINT_ANGLES 0x2100
#define HD_CURRENT_GIMBAL_ANGLES 0x2150
#define HD_CALIBRATION_STYLE 0x2650
#define HD_CURRENT_FORCE 0x2700
#define HD_FORCE_OUTPUT 0x4000
#define HD_CALIBRATION_OK 0x5000
#define HD_CALIBRATION_NEEDS_UPDATE 0x5001
#define HD_CALIBRATION_NEEDS_MANUAL_INPUT 0x5002
#define HD_CALIBRATION_AUTO (1 << 1)
#define HD_CALLBACK_DONE 0
#define HD_CALLBACK_CONTINUE 1

#define MAX_CALLBACKS 8
#define MAX_FORCES 200000

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static int initialized, disabled, force_output, calibration_updated_style;
static double position[3];
static long error_at_ms = -1, nan_at_ms = -1;
static int calibration = HD_CALIBRATION_OK;
static unsigned int pending_error;
static __thread int frame_depth;
static long frames_begun, frames_unbalanced, writes_outside_frame, writes_before_enable;
static long servo_ticks, callbacks_run;
static int64_t scheduler_start_ns = -1;

static struct {
    HDSchedulerCallback cb;
    void *user;
    unsigned short priority;
    int live;
} callbacks[MAX_CALLBACKS];
static pthread_t scheduler;
static volatile int scheduler_running;

static struct {
    double t_ms, f[3];
} forces[MAX_FORCES];
static long force_count;

static int64_t now_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (int64_t)t.tv_sec * 1000000000LL + t.tv_nsec;
}

static double ms_since_start(void) {
    return scheduler_start_ns < 0 ? -1.0 : (now_ns() - scheduler_start_ns) * 1e-6;
}

HHD hdInitDevice(const char *name) {
    (void)name;
    const char *v = getenv("FAKE_HD_INIT");
    if (v && strcmp(v, "fail") == 0) {
        pending_error = HD_COMM_ERROR;
        return HD_INVALID_HANDLE;
    }
    if ((v = getenv("FAKE_HD_POSITION_MM")))
        sscanf(v, "%lf,%lf,%lf", &position[0], &position[1], &position[2]);
    if ((v = getenv("FAKE_HD_CALIBRATION"))) {
        if (strcmp(v, "update") == 0) calibration = HD_CALIBRATION_NEEDS_UPDATE;
        if (strcmp(v, "manual") == 0) calibration = HD_CALIBRATION_NEEDS_MANUAL_INPUT;
    }
    if ((v = getenv("FAKE_HD_ERROR_AT_MS"))) error_at_ms = atol(v);
    if ((v = getenv("FAKE_HD_NAN_AT_MS"))) nan_at_ms = atol(v);
    initialized = 1;
    return 1;
}

void hdMakeCurrentDevice(HHD h) { (void)h; }

HDErrorInfo hdGetError(void) {
    HDErrorInfo e = {0, 0, 1};
    pthread_mutex_lock(&lock);
    e.errorCode = pending_error;
    pending_error = HD_SUCCESS;
    pthread_mutex_unlock(&lock);
    return e;
}

const char *hdGetErrorString(unsigned int code) {
    switch (code) {
    case HD_COMM_ERROR: return "Communication error";
    case HD_ILLEGAL_BEGIN: return "Illegal begin frame";
    default: return "fake libHD error";
    }
}

void hdEnable(HDenum cap) {
    if (cap == HD_FORCE_OUTPUT) force_output = 1;
}

HDenum hdCheckCalibration(void) { return calibration; }

void hdUpdateCalibration(int style) {
    calibration_updated_style = style;
    calibration = HD_CALIBRATION_OK;
}

void hdBeginFrame(HHD h) {
    (void)h;
    if (frame_depth != 0) frames_unbalanced++;
    frame_depth++;
    frames_begun++;
}

void hdEndFrame(HHD h) {
    (void)h;
    if (frame_depth != 1) frames_unbalanced++;
    frame_depth = 0;
}

void hdGetDoublev(HDenum what, double *out) {
    double t = ms_since_start();
    int nan = nan_at_ms >= 0 && t >= nan_at_ms;
    switch (what) {
    case HD_CURRENT_POSITION:
        for (int k = 0; k < 3; k++) out[k] = nan ? NAN : position[k];
        break;
    case HD_CURRENT_VELOCITY:
    case HD_CURRENT_JOINT_ANGLES:
    case HD_CURRENT_GIMBAL_ANGLES:
        for (int k = 0; k < 3; k++) out[k] = 0.0;
        break;
    case HD_CURRENT_TRANSFORM:
        for (int k = 0; k < 16; k++) out[k] = (k % 5 == 0) ? 1.0 : 0.0;
        for (int k = 0; k < 3; k++) out[12 + k] = position[k];
        break;
    default:
        break;
    }
}

void hdGetIntegerv(HDenum what, int *out) {
    if (what == HD_CURRENT_BUTTONS) *out = 0;
    if (what == HD_CALIBRATION_STYLE) *out = HD_CALIBRATION_AUTO;
}

void hdSetDoublev(HDenum what, const double *v) {
    if (what != HD_CURRENT_FORCE) return;
    pthread_mutex_lock(&lock);
    if (frame_depth != 1) writes_outside_frame++;
    if (!force_output && (v[0] != 0.0 || v[1] != 0.0 || v[2] != 0.0)) writes_before_enable++;
    if (force_count < MAX_FORCES) {
        forces[force_count].t_ms = ms_since_start();
        memcpy(forces[force_count].f, v, sizeof forces[0].f);
        force_count++;
    }
    pthread_mutex_unlock(&lock);
}

static void *scheduler_main(void *arg) {
    (void)arg;
    int64_t next = now_ns();
    while (scheduler_running) {
        next += 1000000;
        struct timespec t = {next / 1000000000LL, next % 1000000000LL};
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &t, NULL);
        double ms = ms_since_start();
        if (error_at_ms >= 0 && ms >= error_at_ms) {
            pthread_mutex_lock(&lock);
            pending_error = HD_COMM_ERROR;
            pthread_mutex_unlock(&lock);
            error_at_ms = -1;
        }
        servo_ticks++;
        for (int i = 0; i < MAX_CALLBACKS; i++) {
            if (!callbacks[i].live) continue;
            callbacks_run++;
            if (callbacks[i].cb(callbacks[i].user) == HD_CALLBACK_DONE) callbacks[i].live = 0;
        }
    }
    return NULL;
}

HDSchedulerHandle hdScheduleAsynchronous(HDSchedulerCallback cb, void *user,
                                         unsigned short priority) {
    for (int i = 0; i < MAX_CALLBACKS; i++) {
        if (!callbacks[i].live) {
            callbacks[i].cb = cb;
            callbacks[i].user = user;
            callbacks[i].priority = priority;
            callbacks[i].live = 1;
            return (HDSchedulerHandle)(i + 1);
        }
    }
    return 0;
}

void hdUnschedule(HDSchedulerHandle h) {
    if (h >= 1 && h <= MAX_CALLBACKS) callbacks[h - 1].live = 0;
}

void hdStartScheduler(void) {
    if (scheduler_running) return;
    scheduler_start_ns = now_ns();
    scheduler_running = 1;
    pthread_create(&scheduler, NULL, scheduler_main, NULL);
}

void hdStopScheduler(void) {
    if (!scheduler_running) return;
    scheduler_running = 0;
    pthread_join(scheduler, NULL);
}

static char report_path[4096];

/* Also starts a fresh device: a test process that loads the library several times (one
 * test after another) gets counters and a force log of its own use only. */
void fake_hd_set_report(const char *path) {
    pthread_mutex_lock(&lock);
    snprintf(report_path, sizeof report_path, "%s", path);
    initialized = disabled = force_output = calibration_updated_style = 0;
    position[0] = position[1] = position[2] = 0.0;
    error_at_ms = nan_at_ms = -1;
    calibration = HD_CALIBRATION_OK;
    pending_error = HD_SUCCESS;
    frames_begun = frames_unbalanced = writes_outside_frame = writes_before_enable = 0;
    servo_ticks = callbacks_run = 0;
    scheduler_start_ns = -1;
    force_count = 0;
    for (int i = 0; i < MAX_CALLBACKS; i++) callbacks[i].live = 0;
    pthread_mutex_unlock(&lock);
}

void hdDisableDevice(HHD h) {
    (void)h;
    disabled++;
    const char *path = report_path[0] ? report_path : getenv("FAKE_HD_REPORT");
    if (!path) return;
    FILE *f = fopen(path, "w");
    if (!f) return;
    pthread_mutex_lock(&lock);
    fprintf(f, "initialized %d\n", initialized);
    fprintf(f, "disabled %d\n", disabled);
    fprintf(f, "scheduler_running_at_disable %d\n", scheduler_running);
    fprintf(f, "force_output %d\n", force_output);
    fprintf(f, "calibration_updated_style %d\n", calibration_updated_style);
    fprintf(f, "frames_begun %ld\n", frames_begun);
    fprintf(f, "frames_unbalanced %ld\n", frames_unbalanced);
    fprintf(f, "writes_outside_frame %ld\n", writes_outside_frame);
    fprintf(f, "writes_before_enable %ld\n", writes_before_enable);
    fprintf(f, "servo_ticks %ld\n", servo_ticks);
    fprintf(f, "callbacks_run %ld\n", callbacks_run);
    fprintf(f, "force_writes %ld\n", force_count);
    for (long i = 0; i < force_count; i++)
        fprintf(f, "force %.3f %.9g %.9g %.9g\n", forces[i].t_ms, forces[i].f[0], forces[i].f[1],
                forces[i].f[2]);
    pthread_mutex_unlock(&lock);
    fclose(f);
}
