//! The OpenHaptics HD C API, as far as the bridge uses it, declared as SensAble's headers do.
//!
//! Types and constant values are those of `HD/hdDefines.h` and `HD/hdScheduler.h`
//! (OpenHaptics 3.0; 3.4 keeps them). Every value below was checked against the published
//! `hdDefines.h` / `hdScheduler.h` text, except where a comment says otherwise. Units, as the
//! library reports them: millimetres, newtons, and the transform as 16 doubles, column-major
//! (OpenGL order: element `[12..15]` is the translation).
//!
//! Calling convention: `hdExport.h` declares every function `HDAPIENTRY` and the scheduler
//! callback `HDCALLBACK`, both `__stdcall` on Windows. That is `extern "system"` in Rust:
//! `__stdcall` on 32-bit Windows, and the platform's one C convention on x86-64 (Windows and
//! Linux alike, where the header's `stdcall` attribute has no effect). On 32-bit x86 Linux the
//! header asks for `stdcall` too, which `"system"` is not; the bridge is not built for it.
//!
//! The stand-in library (`maobi-hd-standin`) declares the same items on its side; keep the
//! two in step (the tests load the stand-in through [`super::loader`], so a mismatch in a
//! signature shows up there).

use std::ffi::{c_char, c_int, c_uint, c_ulong, c_ushort, c_void};

/// `HHD`: a device handle.
pub type Hhd = c_uint;
/// `HDerror`.
pub type HdError = c_uint;
/// `HDenum`.
pub type HdEnum = c_uint;
/// `HDboolean` (an `unsigned char` in hdDefines.h).
pub type HdBoolean = u8;
/// `HDCallbackCode` (hdScheduler.h).
pub type HdCallbackCode = c_uint;
/// `HDSchedulerHandle` (hdScheduler.h): an `unsigned long`.
pub type HdSchedulerHandle = c_ulong;
/// `HDstring`: a NUL-terminated string owned by the library.
pub type HdString = *const c_char;

/// `HDSchedulerCallback`: `HDCALLBACK`, `__stdcall` on Windows (see the module docs).
pub type HdSchedulerCallback = unsafe extern "system" fn(user_data: *mut c_void) -> HdCallbackCode;

/// `HDErrorInfo`, which `hdGetError` returns by value.
#[repr(C)]
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct HdErrorInfo {
    /// The `HD_` error code (`HD_SUCCESS` when there is none).
    pub error_code: HdError,
    /// The device's own error code behind it.
    pub internal_error_code: c_int,
    /// The device that was current when the error happened.
    pub h_hd: Hhd,
}

impl HdErrorInfo {
    /// `HD_DEVICE_ERROR(info)` of hdDefines.h.
    pub fn is_error(&self) -> bool {
        self.error_code != HD_SUCCESS
    }
}

// Scheduler callback return codes (hdScheduler.h).
pub const HD_CALLBACK_DONE: HdCallbackCode = 0;
pub const HD_CALLBACK_CONTINUE: HdCallbackCode = 1;

// Error codes.
pub const HD_SUCCESS: HdError = 0x0000;
pub const HD_INVALID_ENUM: HdError = 0x0100;
pub const HD_INVALID_VALUE: HdError = 0x0101;
pub const HD_INVALID_OPERATION: HdError = 0x0102;
pub const HD_INVALID_INPUT_TYPE: HdError = 0x0103;
pub const HD_BAD_HANDLE: HdError = 0x0104;
pub const HD_WARM_MOTORS: HdError = 0x0200;
pub const HD_EXCEEDED_MAX_FORCE: HdError = 0x0201;
pub const HD_EXCEEDED_MAX_FORCE_IMPULSE: HdError = 0x0202;
pub const HD_EXCEEDED_MAX_VELOCITY: HdError = 0x0203;
pub const HD_FORCE_ERROR: HdError = 0x0204;
pub const HD_DEVICE_FAULT: HdError = 0x0300;
pub const HD_DEVICE_ALREADY_INITIATED: HdError = 0x0301;
pub const HD_COMM_ERROR: HdError = 0x0302;
pub const HD_COMM_CONFIG_ERROR: HdError = 0x0303;
pub const HD_TIMER_ERROR: HdError = 0x0304;
pub const HD_ILLEGAL_BEGIN: HdError = 0x0400;
pub const HD_ILLEGAL_END: HdError = 0x0401;
pub const HD_FRAME_ERROR: HdError = 0x0402;
pub const HD_INVALID_PRIORITY: HdError = 0x0500;
pub const HD_SCHEDULER_FULL: HdError = 0x0501;
pub const HD_INVALID_LICENSE: HdError = 0x0600;

// Get-parameter options.
pub const HD_CURRENT_BUTTONS: HdEnum = 0x2000;
pub const HD_CURRENT_SAFETY_SWITCH: HdEnum = 0x2001;
pub const HD_CURRENT_INKWELL_SWITCH: HdEnum = 0x2002;
pub const HD_CURRENT_POSITION: HdEnum = 0x2050;
pub const HD_CURRENT_VELOCITY: HdEnum = 0x2051;
pub const HD_CURRENT_TRANSFORM: HdEnum = 0x2052;
pub const HD_CALIBRATION_STYLE: HdEnum = 0x2555;
pub const HD_UPDATE_RATE: HdEnum = 0x2600;
pub const HD_NOMINAL_MAX_STIFFNESS: HdEnum = 0x2602;
pub const HD_NOMINAL_MAX_FORCE: HdEnum = 0x2603;
pub const HD_NOMINAL_MAX_CONTINUOUS_FORCE: HdEnum = 0x2604;
pub const HD_NOMINAL_MAX_DAMPING: HdEnum = 0x2609;
// Set-parameter option.
pub const HD_CURRENT_FORCE: HdEnum = 0x2700;

// Enable / disable capabilities.
pub const HD_FORCE_OUTPUT: HdEnum = 0x4000;
pub const HD_MAX_FORCE_CLAMPING: HdEnum = 0x4001;
pub const HD_FORCE_RAMPING: HdEnum = 0x4002;
pub const HD_SOFTWARE_FORCE_LIMIT: HdEnum = 0x4003;
pub const HD_ONE_FRAME_LIMIT: HdEnum = 0x4004;

// Scheduler priorities: USHRT_MAX, 0 and their mean, as hdDefines.h computes it.
pub const HD_MAX_SCHEDULER_PRIORITY: c_ushort = c_ushort::MAX;
pub const HD_MIN_SCHEDULER_PRIORITY: c_ushort = 0;
pub const HD_DEFAULT_SCHEDULER_PRIORITY: c_ushort =
    ((HD_MAX_SCHEDULER_PRIORITY as u32 + HD_MIN_SCHEDULER_PRIORITY as u32) / 2) as c_ushort;

// Calibration: what hdCheckCalibration returns, and the styles (a mask in
// HD_CALIBRATION_STYLE; one of them is hdUpdateCalibration's argument).
pub const HD_CALIBRATION_OK: HdEnum = 0x5000;
pub const HD_CALIBRATION_NEEDS_UPDATE: HdEnum = 0x5001;
pub const HD_CALIBRATION_NEEDS_MANUAL_INPUT: HdEnum = 0x5002;
pub const HD_CALIBRATION_ENCODER_RESET: c_int = 1 << 0;
pub const HD_CALIBRATION_AUTO: c_int = 1 << 1;
pub const HD_CALIBRATION_INKWELL: c_int = 1 << 2;

// Button masks.
pub const HD_DEVICE_BUTTON_1: c_int = 1 << 0;
pub const HD_DEVICE_BUTTON_2: c_int = 1 << 1;
pub const HD_DEVICE_BUTTON_3: c_int = 1 << 2;
pub const HD_DEVICE_BUTTON_4: c_int = 1 << 3;

/// What `hdInitDevice` returns on failure.
pub const HD_INVALID_HANDLE: Hhd = 0xFFFF_FFFF;
/// `HD_DEFAULT_DEVICE`: `NULL`, the device configured as the default one.
pub const HD_DEFAULT_DEVICE: HdString = std::ptr::null();

// The functions' C types, one alias per symbol.
pub type FnInitDevice = unsafe extern "system" fn(name: HdString) -> Hhd;
pub type FnDisableDevice = unsafe extern "system" fn(hhd: Hhd);
pub type FnEnable = unsafe extern "system" fn(cap: HdEnum);
pub type FnDisable = unsafe extern "system" fn(cap: HdEnum);
pub type FnStartScheduler = unsafe extern "system" fn();
pub type FnStopScheduler = unsafe extern "system" fn();
pub type FnSetSchedulerRate = unsafe extern "system" fn(rate_hz: c_ulong);
pub type FnScheduleAsynchronous = unsafe extern "system" fn(
    callback: HdSchedulerCallback,
    user_data: *mut c_void,
    priority: c_ushort,
) -> HdSchedulerHandle;
pub type FnUnschedule = unsafe extern "system" fn(handle: HdSchedulerHandle);
pub type FnBeginFrame = unsafe extern "system" fn(hhd: Hhd);
pub type FnEndFrame = unsafe extern "system" fn(hhd: Hhd);
pub type FnGetDoublev = unsafe extern "system" fn(name: HdEnum, values: *mut f64);
pub type FnGetIntegerv = unsafe extern "system" fn(name: HdEnum, values: *mut c_int);
pub type FnSetDoublev = unsafe extern "system" fn(name: HdEnum, values: *const f64);
pub type FnGetError = unsafe extern "system" fn() -> HdErrorInfo;
pub type FnGetErrorString = unsafe extern "system" fn(code: HdError) -> HdString;
pub type FnCheckCalibration = unsafe extern "system" fn() -> HdEnum;
pub type FnUpdateCalibration = unsafe extern "system" fn(style: HdEnum);

/// How the servo loop treats an HD error, as the SDK's `hduError` helpers sort them.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum ErrorClass {
    /// A device warning about the force or the motion (`hduIsForceError`, and the force
    /// impulse limit): the library has limited or refused this force; the loop goes on with
    /// zero force, the simulation reset ("resetting contact or simulation state", as
    /// `hduError.h` puts it) and a fault latched for the user to clear.
    Warning,
    /// Anything else: communication, configuration, timer and scheduler errors
    /// (`hduIsSchedulerError`: the servo loop cannot run properly), device faults, and the
    /// errors of a misused call (frames, handles, enums), which mean the bridge itself is
    /// wrong. The loop stops.
    Fatal,
}

/// The class of an error code (see [`ErrorClass`]).
pub fn classify(code: HdError) -> ErrorClass {
    match code {
        HD_WARM_MOTORS
        | HD_EXCEEDED_MAX_FORCE
        | HD_EXCEEDED_MAX_FORCE_IMPULSE
        | HD_EXCEEDED_MAX_VELOCITY
        | HD_FORCE_ERROR => ErrorClass::Warning,
        _ => ErrorClass::Fatal,
    }
}

/// The name of a calibration status (hdCheckCalibration's result), for messages.
pub fn calibration_name(status: HdEnum) -> &'static str {
    match status {
        HD_CALIBRATION_OK => "HD_CALIBRATION_OK",
        HD_CALIBRATION_NEEDS_UPDATE => "HD_CALIBRATION_NEEDS_UPDATE",
        HD_CALIBRATION_NEEDS_MANUAL_INPUT => "HD_CALIBRATION_NEEDS_MANUAL_INPUT",
        _ => "an unknown calibration status",
    }
}

/// The name of an error code, for messages (the library's own text comes from
/// `hdGetErrorString`).
pub fn error_name(code: HdError) -> &'static str {
    match code {
        HD_SUCCESS => "HD_SUCCESS",
        HD_INVALID_ENUM => "HD_INVALID_ENUM",
        HD_INVALID_VALUE => "HD_INVALID_VALUE",
        HD_INVALID_OPERATION => "HD_INVALID_OPERATION",
        HD_INVALID_INPUT_TYPE => "HD_INVALID_INPUT_TYPE",
        HD_BAD_HANDLE => "HD_BAD_HANDLE",
        HD_WARM_MOTORS => "HD_WARM_MOTORS",
        HD_EXCEEDED_MAX_FORCE => "HD_EXCEEDED_MAX_FORCE",
        HD_EXCEEDED_MAX_FORCE_IMPULSE => "HD_EXCEEDED_MAX_FORCE_IMPULSE",
        HD_EXCEEDED_MAX_VELOCITY => "HD_EXCEEDED_MAX_VELOCITY",
        HD_FORCE_ERROR => "HD_FORCE_ERROR",
        HD_DEVICE_FAULT => "HD_DEVICE_FAULT",
        HD_DEVICE_ALREADY_INITIATED => "HD_DEVICE_ALREADY_INITIATED",
        HD_COMM_ERROR => "HD_COMM_ERROR",
        HD_COMM_CONFIG_ERROR => "HD_COMM_CONFIG_ERROR",
        HD_TIMER_ERROR => "HD_TIMER_ERROR",
        HD_ILLEGAL_BEGIN => "HD_ILLEGAL_BEGIN",
        HD_ILLEGAL_END => "HD_ILLEGAL_END",
        HD_FRAME_ERROR => "HD_FRAME_ERROR",
        HD_INVALID_PRIORITY => "HD_INVALID_PRIORITY",
        HD_SCHEDULER_FULL => "HD_SCHEDULER_FULL",
        HD_INVALID_LICENSE => "HD_INVALID_LICENSE",
        _ => "an unknown HD error",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_info_has_the_c_layout() {
        // Three 4-byte fields, no padding: what `hdGetError` returns in registers on x86-64.
        assert_eq!(std::mem::size_of::<HdErrorInfo>(), 12);
        assert_eq!(std::mem::align_of::<HdErrorInfo>(), 4);
        assert_eq!(HD_DEFAULT_SCHEDULER_PRIORITY, 32767);
    }

    #[test]
    fn errors_are_sorted_as_the_sdk_sorts_them() {
        for w in [
            HD_WARM_MOTORS,
            HD_EXCEEDED_MAX_FORCE,
            HD_EXCEEDED_MAX_FORCE_IMPULSE,
            HD_EXCEEDED_MAX_VELOCITY,
            HD_FORCE_ERROR,
        ] {
            assert_eq!(classify(w), ErrorClass::Warning, "{}", error_name(w));
        }
        for f in [
            HD_COMM_ERROR,
            HD_COMM_CONFIG_ERROR,
            HD_TIMER_ERROR,
            HD_INVALID_PRIORITY,
            HD_SCHEDULER_FULL,
            HD_DEVICE_FAULT,
            HD_ILLEGAL_BEGIN,
            HD_ILLEGAL_END,
            HD_BAD_HANDLE,
            0x7777,
        ] {
            assert_eq!(classify(f), ErrorClass::Fatal, "{}", error_name(f));
        }
    }
}
