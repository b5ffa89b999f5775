//! The pen's configuration in flash: sector 7 (0x0806_0000, 128 KiB), which the workspace
//! root `memory.x` keeps out of the image.
//!
//! The sector is a log of fixed-size slots, each holding one image of `pen_io::config`'s
//! codec (magic, format version, length, postcard payload, CRC-32). A write goes into the
//! first erased slot after the newest; only when the sector is full is it erased (every
//! [`SLOTS`] writes), which saves both the flash's endurance and the 1-2 s stall of a
//! 128 KiB erase. [`ConfigStore::load`] copies the newest slot (the last one not erased),
//! which the link task decodes: missing, damaged, truncated (a write cut short by a reset)
//! or invalid all leave the pen without a configuration and so without forces, and the
//! handshake says which (`ConfigState`). An older image is never used in place of a bad
//! newer one: it would bring back a calibration the builder replaced.
//!
//! While flash is being written or erased, the core cannot fetch from it: the force loop's
//! interrupt waits. Writes happen only with the forces off; [`ConfigStore::store`] turns
//! the motors off, marks the pause ([`crate::app::MAINTENANCE`]) so that the supervisor
//! does not take it for a stall, and stretches the hardware watchdog over an erase.

use embassy_stm32::flash::{Blocking, Flash};
use maobi_shared::pen_io::config::CONFIG_IMAGE_MAX;

use super::watchdog;
use crate::board::{ConfigStore, StoreError};

/// Offset of the configuration sector from the start of flash (0x0800_0000); see
/// `memory.x` at the workspace root, which ends FLASH here.
pub const CONFIG_OFFSET: u32 = 0x6_0000;
/// Size of the sector (sector 7 of the STM32F411CE).
pub const CONFIG_SECTOR: u32 = 0x2_0000;
/// One image per slot; the largest image must fit.
pub const SLOT: u32 = 512;
pub const SLOTS: u32 = CONFIG_SECTOR / SLOT;
const _: () = assert!(CONFIG_IMAGE_MAX as u32 <= SLOT);
// The F4 programs 4-byte words; slots start on word boundaries.
const _: () = assert!(SLOT.is_multiple_of(embassy_stm32::flash::WRITE_SIZE as u32));

pub struct FlashConfig {
    flash: Flash<'static, Blocking>,
    /// The newest slot written (`None`: the sector is erased, no image).
    newest: Option<u32>,
    /// Index of the first erased slot (`SLOTS`: the sector is full).
    next_free: u32,
}

/// Whether `bytes` are all erased flash.
fn erased(bytes: &[u8]) -> bool {
    bytes.iter().all(|&b| b == 0xFF)
}

impl FlashConfig {
    /// Finds the newest image (the last slot before the first erased one).
    pub fn open(mut flash: Flash<'static, Blocking>) -> Self {
        let mut slot = [0u8; SLOT as usize];
        let mut newest = None;
        let mut next_free = SLOTS;
        for i in 0..SLOTS {
            if flash.blocking_read(CONFIG_OFFSET + i * SLOT, &mut slot).is_err() {
                break;
            }
            if erased(&slot) {
                next_free = i;
                break;
            }
            newest = Some(i);
        }
        FlashConfig {
            flash,
            newest,
            next_free,
        }
    }
}

impl ConfigStore for FlashConfig {
    /// Copies the newest slot; with none written, an erased slot's `0xFF`s (`decode`:
    /// erased, so `Missing`). A slot that cannot be read comes back as zeros, which
    /// `decode` rejects.
    fn load(&mut self, buf: &mut [u8]) -> usize {
        let n = buf.len().min(SLOT as usize);
        let Some(out) = buf.get_mut(..n) else {
            return 0;
        };
        match self.newest {
            None => out.fill(0xFF),
            Some(i) => {
                if self
                    .flash
                    .blocking_read(CONFIG_OFFSET + i * SLOT, out)
                    .is_err()
                {
                    out.fill(0);
                }
            }
        }
        n
    }

    /// Appends `image` as the newest slot and reads it back. The link task calls this only
    /// with the forces off; the motors are turned off here as well, for the pause.
    fn store(&mut self, image: &[u8]) -> Result<(), StoreError> {
        let mut slot = [0xFFu8; SLOT as usize];
        slot.get_mut(..image.len())
            .ok_or(StoreError::TooLarge)?
            .copy_from_slice(image);
        // Whole words: the bytes after the image stay 0xFF (erased), as decode expects.
        let len = image
            .len()
            .next_multiple_of(embassy_stm32::flash::WRITE_SIZE)
            .min(SLOT as usize);
        let _pause = crate::app::Maintenance::begin(super::motors::motors_off);
        if self.next_free >= SLOTS {
            // Full: erase the sector (1-2 s with the core stalled; the watchdog is stretched
            // over it and put back after).
            let _long = watchdog::Stretch::begin();
            self.newest = None;
            self.flash
                .blocking_erase(CONFIG_OFFSET, CONFIG_OFFSET + CONFIG_SECTOR)
                .map_err(|_| StoreError::Write)?;
            self.next_free = 0;
        }
        let at = CONFIG_OFFSET + self.next_free * SLOT;
        // The slot is the newest from here on, whatever happens: a half-written slot is not
        // erased, never written into again, and loads as what it is (corrupt), not as the
        // older image before it.
        self.newest = Some(self.next_free);
        self.next_free += 1;
        let written = self.flash.blocking_write(at, &slot[..len]);
        let mut back = [0u8; SLOT as usize];
        let read = self.flash.blocking_read(at, &mut back[..len]);
        match (written, read) {
            (Ok(()), Ok(())) if back[..len] == slot[..len] => Ok(()),
            (Ok(()), Ok(())) => {
                defmt::error!("configuration not stored: it reads back differently");
                Err(StoreError::Verify)
            }
            _ => {
                defmt::error!("configuration not stored: the flash reported an error");
                Err(StoreError::Write)
            }
        }
    }
}
