//! The pen's configuration in flash: sectors 6 and 7 (0x0804_0000..0x0808_0000, 128 KiB
//! each), which the workspace root `memory.x` keeps out of the image.
//!
//! The two sectors hold `maobi_shared::pen_io::ConfigLog`, a log of 512-byte slots, each
//! one image of `pen_io::config`'s codec (magic, format version, length, postcard payload,
//! CRC-32) with a trailer (a sequence number and its complement) programmed only after the
//! image has been read back. The log's logic (which slot is the newest, where the next save
//! goes, when a sector is erased, what a power loss at any byte leaves) is in the shared
//! crate and tested on the host against a NOR flash model (`shared/tests/config_log.rs`);
//! this file gives it the chip's flash and the pauses a write needs.
//!
//! Why two sectors: a sector is erased only when the log moves into it, every 256 saves,
//! and it then never holds the newest save, so a power loss during the erase (2 s typical,
//! 4 s at most: see [`PausingFlash`]) or during any write leaves the save in progress or the
//! one before, never nothing. A single sector would lose its only copy to that erase.
//!
//! [`ConfigStore::load`] copies the newest committed slot, which the link task decodes: a
//! save cut short by a reset was never committed and is skipped (the host was never told
//! it succeeded); a committed image that does not decode (damaged since, a format version
//! this firmware does not read) leaves the pen without a configuration and so without
//! forces, and the handshake says which (`ConfigState`). A format-1 image is migrated by
//! the link task (`pen_io::load`): kinematics and calibration, no force until completed. An older image is never used in place of a bad
//! committed one: it would bring back a configuration the builder replaced.
//!
//! While flash is being written or erased, the core cannot fetch from it: the force loop's
//! interrupt waits. Writes happen only with the forces off; [`ConfigStore::store`] turns
//! the motors off and marks the pause ([`crate::app::MAINTENANCE`]) so that the supervisor
//! does not take it for a stall, and stretches the hardware watchdog over the whole store
//! ([`PausingFlash`] over every erase, the boot's reclaim included).

use embassy_stm32::flash::{Blocking, Error as FlashError, Flash};
use embassy_stm32::pac;
use maobi_shared::pen_io::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use maobi_shared::pen_io::{
    flash_acr, ConfigLog, LogError, Region, CONFIG_IMAGE_MAX, CONFIG_MAGIC,
};

use super::watchdog;
use crate::board::{ConfigStore, StoreError};

/// Offset of the configuration sectors from the start of flash (0x0800_0000): sector 6;
/// see `memory.x` at the workspace root, which ends FLASH here.
pub const CONFIG_OFFSET: u32 = 0x4_0000;
/// Sectors 6 and 7 of the STM32F411CE, 128 KiB each (embassy's `ERASE_SIZE` for this chip,
/// its largest sector).
pub const CONFIG_SECTORS: u32 = 2;
/// One image per slot; the largest image and the trailer must fit.
pub const SLOT: usize = 512;

type Log = ConfigLog<PausingFlash, SLOT>;
/// Checked when compiled: sector-aligned, whole slots per sector, whole write units.
const REGION: Region = Region::new::<PausingFlash, SLOT>(CONFIG_OFFSET, CONFIG_SECTORS);
const _: () = assert!(CONFIG_IMAGE_MAX <= Log::IMAGE_ROOM);
// The region is the chip's last two sectors, both 128 KiB.
const _: () = assert!(
    CONFIG_OFFSET as usize + CONFIG_SECTORS as usize * <PausingFlash as NorFlash>::ERASE_SIZE
        == 512 * 1024
);

/// The chip's flash, with the watchdog stretched over every erase and put back after.
///
/// An erase stalls the core for 2 s typical, 4 s at most per 128 KiB sector (the
/// STM32F411's datasheet, t_ERASE128KB at program/erase parallelism x8), far beyond the
/// watchdog's 80 ms; twice that when both configuration sectors are erased in one call (the
/// boot's reclaim). x8, not the x32 whose 1 s typical / 2 s max an earlier comment quoted:
/// embassy's erase only adds SER and SNB to `FLASH_CR`, whose PSIZE its writes leave cleared
/// (their end rewrites the register with PG alone) and reset leaves cleared, and PSIZE 00
/// is x8. The stretched watchdog (22 s at the fastest LSI, `watchdog::Stretch`) covers both.
pub struct PausingFlash(Flash<'static, Blocking>);

impl ErrorType for PausingFlash {
    type Error = FlashError;
}

impl ReadNorFlash for PausingFlash {
    const READ_SIZE: usize = <Flash<'static, Blocking> as ReadNorFlash>::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        self.0.blocking_read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl NorFlash for PausingFlash {
    const WRITE_SIZE: usize = <Flash<'static, Blocking> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = <Flash<'static, Blocking> as NorFlash>::ERASE_SIZE;

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let r = self.0.blocking_write(offset, bytes);
        // The data cache may still hold these bytes as they read before (the log reads a
        // slot blank, programs it, then reads it back to verify).
        restart_flash_caches();
        r
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let _long = watchdog::Stretch::begin();
        let r = self.0.blocking_erase(from, to);
        restart_flash_caches();
        r
    }
}

pub struct FlashConfig {
    log: Log,
}

impl FlashConfig {
    /// Finds the newest committed save (reads every slot's trailer once).
    pub fn open(flash: Flash<'static, Blocking>) -> Self {
        FlashConfig {
            log: Log::open(PausingFlash(flash), REGION),
        }
    }

    /// Erases the sectors if they hold no save of this firmware's but are not blank
    /// (`ConfigLog::reclaim`: a new board's demo firmware, an interrupted first save), so
    /// that the first save does not stall on an erase while the host waits for its answer.
    /// Called at boot with the motors off and the watchdog running (each erase stretches
    /// it); `probe-rs erase` before the first flash does the same from the host.
    pub fn reclaim(&mut self) {
        match self.log.reclaim(&CONFIG_MAGIC) {
            Ok(0) => {}
            Ok(n) => defmt::warn!(
                "configuration sectors held no Maobi configuration but other data: {=u32} erased",
                n
            ),
            Err(_) => defmt::error!("configuration sectors: erasing foreign data failed"),
        }
    }
}

impl ConfigStore for FlashConfig {
    /// Copies the newest save's slot; with none, erased bytes (`decode`: erased, so
    /// `Missing`). A slot that cannot be read comes back as zeros, which `decode` rejects.
    fn load(&mut self, buf: &mut [u8]) -> usize {
        self.log.load(buf)
    }

    /// Saves `image` as the newest slot (erasing a sector first every 256 saves), reads it
    /// back, then commits it. The link task calls this only with the forces off; the
    /// motors are turned off here as well, for the pause.
    ///
    /// The watchdog is stretched over the whole store, not only its erases: the link task
    /// programs and reads back without yielding, so the supervisor cannot check in
    /// meanwhile and the force tick stops feeding the watchdog, and programming a slot at
    /// the datasheet's slowest byte time would take most of the watchdog's normal timeout.
    /// It is back to that timeout, counting afresh, when the store returns.
    fn store(&mut self, image: &[u8]) -> Result<(), StoreError> {
        let _pause = crate::app::Maintenance::begin(super::motors::motors_off);
        let _long = watchdog::Stretch::begin();
        self.log.store(image).map_err(|e| match e {
            LogError::TooLarge => StoreError::TooLarge,
            LogError::Verify => {
                defmt::error!("configuration not stored: it reads back differently");
                StoreError::Verify
            }
            LogError::Flash(_) => {
                defmt::error!("configuration not stored: the flash reported an error");
                StoreError::Write
            }
        })
    }
}

/// Prefetch and both flash caches on, the caches reset first
/// ([`maobi_shared::pen_io::flash_acr::cache_restart`], tested on the host): at boot, after
/// embassy's clock setup turned them off, and after every flash write or erase
/// ([`PausingFlash`]), which may leave the data cache holding what the flash held
/// before.
pub fn restart_flash_caches() {
    let acr = pac::FLASH.acr();
    for v in flash_acr::cache_restart(acr.read().0) {
        acr.write_value(pac::flash::regs::Acr(v));
    }
}
