//! The QEMU board's configuration store: a RAM region outside the image that stands in for
//! the physical pen's flash page.
//!
//! | what | where |
//! |---|---|
//! | region | [`CONFIG_REGION`] = `0x2100_0000`, [`CONFIG_REGION_LEN`] = 4 KiB: the start of the mps2-an386's 16 MiB PSRAM (`0x2100_0000..0x2200_0000`), which neither the image (code at `0x0`, data at `0x2000_0000`, see `boards/qemu-mps2-an386/memory.x`) nor the stack touches |
//! | preload | `qemu-system-arm ... -device loader,file=cfg.bin,addr=0x21000000` (QEMU's generic loader writes the file's bytes there before the CPU starts) |
//!
//! QEMU zeroes RAM, so a run without a file finds the region all zero: no store attached,
//! and the virtual pen needs no configuration ([`ConfigStore::needs_config`] is false, the
//! handshake says `NotApplicable`, forces behave as they always have). Any loaded file
//! attaches it: from then on the image must decode, or the pen starts safe (forces
//! refused) and the handshake says why. A file of `0xFF` bytes is erased flash
//! (`Missing`); a truncated file leaves the rest of the region zero, which `decode` reports
//! as truncated. `SetConfig` writes the region like flash (erase to `0xFF`, program,
//! verify) and attaches it.

use core::ptr::{read_volatile, write_volatile};

use crate::board::{ConfigStore, StoreError};

/// Start of the region (the PSRAM's base).
pub const CONFIG_REGION: usize = 0x2100_0000;
/// Its length: a page, like the flash page a physical board gives the image.
pub const CONFIG_REGION_LEN: usize = 4096;

pub struct RamConfigStore {
    attached: bool,
}

impl RamConfigStore {
    /// Looks at the region once: anything but zeros means the host loaded an image.
    pub fn open() -> Self {
        let attached = (0..CONFIG_REGION_LEN).any(|i| read(i) != 0);
        RamConfigStore { attached }
    }
}

fn read(offset: usize) -> u8 {
    // SAFETY: `offset < CONFIG_REGION_LEN`: inside the PSRAM, which nothing else uses.
    unsafe { read_volatile((CONFIG_REGION + offset) as *const u8) }
}

fn write(offset: usize, v: u8) {
    // SAFETY: as for `read`; only the link task (one context) writes the region.
    unsafe { write_volatile((CONFIG_REGION + offset) as *mut u8, v) }
}

impl ConfigStore for RamConfigStore {
    fn load(&mut self, buf: &mut [u8]) -> usize {
        let n = buf.len().min(CONFIG_REGION_LEN);
        for (i, b) in buf.iter_mut().take(n).enumerate() {
            *b = read(i);
        }
        n
    }

    fn store(&mut self, image: &[u8]) -> Result<(), StoreError> {
        if image.len() > CONFIG_REGION_LEN {
            return Err(StoreError::TooLarge);
        }
        // As flash: erase the page, program the image, read it back.
        for i in 0..CONFIG_REGION_LEN {
            write(i, 0xFF);
        }
        for (i, &b) in image.iter().enumerate() {
            write(i, b);
        }
        self.attached = true;
        if image.iter().enumerate().any(|(i, &b)| read(i) != b) {
            return Err(StoreError::Verify);
        }
        Ok(())
    }

    fn needs_config(&self) -> bool {
        self.attached
    }
}
