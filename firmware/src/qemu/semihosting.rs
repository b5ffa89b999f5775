//! Semihosting: text output, the command line QEMU passes (`-semihosting-config
//! ...,arg=...`), and exiting QEMU with a status code.

use core::fmt::{self, Write};

/// Text to the host's stdout.
pub struct Stdout;

impl Write for Stdout {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        cortex_m_semihosting::export::hstdout_str(s);
        Ok(())
    }
}

/// Writes raw bytes to the host's stderr (defmt frames).
pub fn stderr_bytes(bytes: &[u8]) {
    if let Ok(mut e) = cortex_m_semihosting::hio::hstderr() {
        let _ = e.write_all(bytes);
    }
}

/// Ends the emulation with `code` as QEMU's exit status (SYS_EXIT_EXTENDED).
pub fn exit(code: u32) -> ! {
    // ADP_Stopped_ApplicationExit with a status code.
    let block: [u32; 2] = [0x2_0026, code];
    // SAFETY: SYS_EXIT_EXTENDED (0x20) reads the two-word block; QEMU exits.
    unsafe {
        cortex_m_semihosting::syscall1(0x20, block.as_ptr() as usize);
    }
    // Not reached under QEMU; on a debugger that ignores the call, stop here.
    loop {
        cortex_m::asm::wfi();
    }
}

/// Prints `msg` and exits with `code` (panics, faults, watchdog).
pub fn fatal(msg: &str, code: u32) -> ! {
    cortex_m_semihosting::export::hstdout_str("FATAL ");
    cortex_m_semihosting::export::hstdout_str(msg);
    cortex_m_semihosting::export::hstdout_str("\n");
    exit(code)
}

pub fn fatal_fmt(args: fmt::Arguments, code: u32) -> ! {
    let _ = Stdout.write_str("FATAL ");
    let _ = Stdout.write_fmt(args);
    let _ = Stdout.write_str("\n");
    exit(code)
}

/// The semihosting command line into `buf`; returns it as a string ("" if unavailable).
pub fn cmdline(buf: &mut [u8]) -> &str {
    let mut block: [usize; 2] = [buf.as_mut_ptr() as usize, buf.len()];
    // SAFETY: SYS_GET_CMDLINE (0x15) writes at most `len` bytes into `buf` and the length
    // into the block.
    let r = unsafe { cortex_m_semihosting::syscall1(0x15, block.as_mut_ptr() as usize) };
    if r != 0 {
        return "";
    }
    let n = block[1].min(buf.len());
    core::str::from_utf8(&buf[..n]).unwrap_or("")
}
