//! The configuration image's home in NOR flash: a log of fixed-size slots over one or more
//! erase sectors, written so that losing power at any moment leaves either the save in
//! progress or the one before it, never a mixture.
//!
//! Written against `embedded-storage`'s [`NorFlash`] (erase sets bytes to `0xFF`; a write
//! only clears bits, in units of [`NorFlash::WRITE_SIZE`]), which embassy-stm32's flash
//! driver implements on the Black Pill and an in-memory model implements in
//! `shared/tests/config_log.rs`. The log does not look inside the image: it stores bytes
//! and hands back the newest complete ones; [`super::decode`] judges them.
//!
//! # A slot
//!
//! | bytes | what |
//! |---|---|
//! | `0 .. SLOT - 8` | the image ([`super::config`]'s format), then erased bytes |
//! | `SLOT - 8 .. SLOT - 4` | the save's sequence number `seq`, `u32` little-endian, from 1 |
//! | `SLOT - 4 .. SLOT` | its complement `!seq`: the commit |
//!
//! A trailer counts only if the complement matches. Erasing only turns bits to 1 and
//! programming only turns them to 0, so a trailer that a cut erase or a cut write left half
//! done has bits moved one way in both words, and `!seq` no longer matches: such a slot is
//! never taken for a save, whatever its sequence number reads as. (`seq` starts at 1 so that
//! an unprogrammed complement, `0xFFFF_FFFF`, never matches.)
//!
//! # Saving ([`ConfigLog::store`])
//!
//! 1. Choose the slot: the first erased one after the newest committed slot, in that slot's
//!    sector. When the sector has none left, the log moves to the next sector (cyclically)
//!    and erases it first unless it is already blank. With two or more sectors that sector
//!    never holds the newest save, so the newest survives the erase.
//! 2. Program the image, read it back.
//! 3. Only then program the trailer (sequence number and its complement), read it back.
//!
//! # Loading ([`ConfigLog::open`], [`ConfigLog::load`])
//!
//! The newest save is the committed slot with the highest sequence number, wherever it is.
//! A slot without a matching complement is a save that did not finish (power lost while programming
//! it, or a failed read-back) and is skipped: the save before it is the newest, which is
//! what the host was last told was stored. The sequence number, not the position, orders
//! the saves, so committed slots an interrupted erase left behind in a sector (which are
//! older than everything in the other sectors) are never taken for the newest.
//!
//! A committed slot whose image does not decode (a bit flipped in flash since, or an image
//! of a format version the firmware does not read, after an update; format 1 is migrated:
//! [`super::load`]) is still the newest: the pen reports
//! it as corrupt and refuses forces rather than bring back an older configuration (and
//! calibration) that the builder had replaced and been told was replaced.
//!
//! # What power loss can do
//!
//! * during the image or the trailer of a save: the slot's trailer does not match (it is
//!   committed only once its last byte is programmed), so the previous save loads;
//! * during a sector erase: the sector being erased holds only saves older than the newest
//!   (with two or more sectors), so the newest loads. With a single sector the erase
//!   destroys the only copy: a power loss between the erase and the end of the following
//!   save leaves no configuration ([`super::ConfigState::Missing`]), or, cut early in the
//!   erase, an older save the erase had not reached yet, or the newest slot's half-erased
//!   image (reported corrupt). The pen starts safe either way, but the builder has to
//!   write the configuration again. That is why the Black Pill gives the log two sectors.
//!
//! `shared/tests/config_log.rs` checks these against a flash model that enforces NOR rules
//! and cuts power at any byte of any write or erase.

use embedded_storage::nor_flash::NorFlash;

/// Sequence number and its complement at the end of every slot.
pub const TRAILER_LEN: usize = 8;

/// Bytes read at a time when comparing or blank-checking (a small stack buffer, not a
/// second slot).
const CHUNK: usize = 64;

/// The trailer of save `seq`.
pub fn trailer(seq: u32) -> [u8; TRAILER_LEN] {
    let [s0, s1, s2, s3] = seq.to_le_bytes();
    let [c0, c1, c2, c3] = (!seq).to_le_bytes();
    [s0, s1, s2, s3, c0, c1, c2, c3]
}

/// The sequence number of a committed slot's trailer; `None` if the complement does not
/// match (erased, half programmed, half erased).
pub fn committed(trailer: [u8; TRAILER_LEN]) -> Option<u32> {
    let [s0, s1, s2, s3, c0, c1, c2, c3] = trailer;
    let seq = u32::from_le_bytes([s0, s1, s2, s3]);
    (u32::from_le_bytes([c0, c1, c2, c3]) == !seq && seq != 0).then_some(seq)
}

/// Where the log lives in the flash `F`: `sectors` erase sectors ([`NorFlash::ERASE_SIZE`]
/// bytes each) from offset `base`.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Region {
    pub base: u32,
    pub sectors: u32,
}

impl Region {
    /// The region, checked against `F`'s erase sector size and the slot size `SLOT`: `base`
    /// on a sector boundary, at least one sector, a whole number of slots per sector, slots
    /// and trailers in whole write units. Used in a `const` the checks are compile errors.
    pub const fn new<F: NorFlash, const SLOT: usize>(base: u32, sectors: u32) -> Region {
        assert!(sectors >= 1, "the log needs a sector");
        assert!(F::ERASE_SIZE > 0 && F::WRITE_SIZE > 0 && F::READ_SIZE > 0);
        assert!(CHUNK.is_multiple_of(F::READ_SIZE) && TRAILER_LEN.is_multiple_of(F::READ_SIZE));
        assert!(
            (base as usize).is_multiple_of(F::ERASE_SIZE),
            "base on a sector boundary"
        );
        assert!(F::ERASE_SIZE.is_multiple_of(SLOT), "whole slots per sector");
        assert!(SLOT > TRAILER_LEN, "room for an image");
        assert!(SLOT.is_multiple_of(F::WRITE_SIZE) && TRAILER_LEN.is_multiple_of(F::WRITE_SIZE));
        assert!(
            SLOT.is_multiple_of(CHUNK),
            "slots in whole read-back chunks"
        );
        assert!(
            (base as u64) + (sectors as u64) * (F::ERASE_SIZE as u64) <= u32::MAX as u64,
            "within the flash's 32-bit offsets"
        );
        Region { base, sectors }
    }
}

/// Why a save did not happen.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum LogError<E> {
    /// The image does not fit a slot (with its trailer).
    TooLarge,
    /// The flash reported an error while erasing, programming or reading back.
    Flash(E),
    /// What was read back differs from what was programmed: the slot stays uncommitted
    /// (skipped by every later load) and the previous save stays the newest.
    Verify,
}

/// The configuration log over the flash `F`, in slots of `SLOT` bytes.
pub struct ConfigLog<F, const SLOT: usize> {
    flash: F,
    region: Region,
    /// Index (over the whole region) of the newest committed slot.
    newest: Option<u32>,
    /// Sequence number of the next save.
    next_seq: u32,
}

impl<F: NorFlash, const SLOT: usize> ConfigLog<F, SLOT> {
    /// Bytes of a slot the image may use.
    pub const IMAGE_ROOM: usize = SLOT - TRAILER_LEN;
    const SLOTS_PER_SECTOR: u32 = (F::ERASE_SIZE / SLOT) as u32;

    /// Scans the region for the newest committed slot (one read of each slot's trailer). A
    /// trailer that cannot be read counts as uncommitted.
    pub fn open(mut flash: F, region: Region) -> Self {
        let slots = region.sectors * Self::SLOTS_PER_SECTOR;
        let mut newest: Option<(u32, u32)> = None;
        for i in 0..slots {
            let mut trailer = [0u8; TRAILER_LEN];
            let at = Self::offset(region, i) + Self::IMAGE_ROOM as u32;
            if flash.read(at, &mut trailer).is_err() {
                continue;
            }
            let Some(seq) = committed(trailer) else {
                continue;
            };
            if newest.is_none_or(|(_, best)| seq >= best) {
                newest = Some((i, seq));
            }
        }
        ConfigLog {
            flash,
            region,
            newest: newest.map(|(i, _)| i),
            // Saturates rather than wraps: 2^32 saves is far beyond any flash's endurance.
            next_seq: newest.map_or(1, |(_, seq)| seq.saturating_add(1)),
        }
    }

    /// Copies the newest save's slot (its image and the erased bytes after it, at most
    /// `buf.len()` bytes) into `buf`; returns how many bytes that is. With no save, erased
    /// bytes (`0xFF`, which `decode` reports as erased); if the slot cannot be read, zeros
    /// (which `decode` rejects).
    pub fn load(&mut self, buf: &mut [u8]) -> usize {
        let n = buf.len().min(Self::IMAGE_ROOM);
        let Some(out) = buf.get_mut(..n) else {
            return 0;
        };
        match self.newest {
            None => out.fill(0xFF),
            Some(i) => {
                if self.flash.read(Self::offset(self.region, i), out).is_err() {
                    out.fill(0);
                }
            }
        }
        n
    }

    /// Saves `image` as the newest: erases a sector first if the log moves into one that
    /// is not blank, programs the image into the next erased slot, reads it back, then
    /// commits it. On any error the previous save stays the newest.
    pub fn store(&mut self, image: &[u8]) -> Result<(), LogError<F::Error>> {
        if image.len() > Self::IMAGE_ROOM {
            return Err(LogError::TooLarge);
        }
        let mut slot = [0xFFu8; SLOT];
        slot.get_mut(..image.len())
            .ok_or(LogError::TooLarge)?
            .copy_from_slice(image);
        // Whole write units; the bytes after the image stay erased.
        let len = image.len().next_multiple_of(F::WRITE_SIZE);
        let programmed = slot.get(..len).ok_or(LogError::TooLarge)?;

        let target = self.next_slot()?;
        let at = Self::offset(self.region, target);
        let seq = self.next_seq;
        // From here on the slot is not erased: `next_slot` passes over it next time
        // whatever happens, and it is the newest only once committed.
        self.next_seq = seq.saturating_add(1);
        self.program_verified(at, programmed)?;
        self.program_verified(at + Self::IMAGE_ROOM as u32, &trailer(seq))?;
        self.newest = Some(target);
        Ok(())
    }

    /// Takes the region over from whatever else wrote it, so that the first save does not
    /// stall on an erase: a board calls this once at boot, before anything is timed.
    ///
    /// The region is the log's own when its newest committed slot holds an image starting
    /// with `magic` (the configuration image's [`super::CONFIG_MAGIC`]), or when it is all
    /// erased: then nothing is touched. Otherwise it holds nothing a load would ever hand
    /// out as a configuration (another firmware's data, such as the demo a board ships
    /// with; the start of a first save cut short; a committed image that is not one of
    /// ours), and every sector that is not blank is erased now. Without this the first
    /// save would find no erased slot and erase a sector while the host waits for its
    /// answer. Returns the number of sectors erased.
    pub fn reclaim(&mut self, magic: &[u8]) -> Result<u32, LogError<F::Error>> {
        if let Some(i) = self.newest {
            let mut head = [0u8; CHUNK];
            let head = head.get_mut(..magic.len()).ok_or(LogError::TooLarge)?;
            self.flash
                .read(Self::offset(self.region, i), head)
                .map_err(LogError::Flash)?;
            if head == magic {
                return Ok(0);
            }
        }
        // Nothing here is a save of ours, whatever the erases below leave.
        self.newest = None;
        self.next_seq = 1;
        let per = Self::SLOTS_PER_SECTOR;
        let mut erased = 0;
        for sector in 0..self.region.sectors {
            if self.blank(sector * per, per)? {
                continue;
            }
            let from = Self::offset(self.region, sector * per);
            self.flash
                .erase(from, from + F::ERASE_SIZE as u32)
                .map_err(LogError::Flash)?;
            erased += 1;
        }
        Ok(erased)
    }

    /// The newest committed slot's index over the region (for tests and logs).
    pub fn newest_slot(&self) -> Option<u32> {
        self.newest
    }

    /// Slots in the region.
    pub fn slots(&self) -> u32 {
        self.region.sectors * Self::SLOTS_PER_SECTOR
    }

    /// The flash back (a test's power cycle: take it, reopen the log).
    pub fn into_inner(self) -> F {
        self.flash
    }

    fn offset(region: Region, slot: u32) -> u32 {
        region.base + slot * SLOT as u32
    }

    /// Programs `bytes` at `at` and reads them back.
    fn program_verified(&mut self, at: u32, bytes: &[u8]) -> Result<(), LogError<F::Error>> {
        self.flash.write(at, bytes).map_err(LogError::Flash)?;
        // Compared in chunks: no second slot-sized buffer on the stack.
        let mut back = [0u8; CHUNK];
        for (k, chunk) in bytes.chunks(CHUNK).enumerate() {
            let dst = back.get_mut(..chunk.len()).ok_or(LogError::Verify)?;
            let off = at + (k * CHUNK) as u32;
            self.flash.read(off, dst).map_err(LogError::Flash)?;
            if dst != chunk {
                return Err(LogError::Verify);
            }
        }
        Ok(())
    }

    /// The slot the next save goes to, erasing its sector first when the log moves into a
    /// sector that is not blank.
    fn next_slot(&mut self) -> Result<u32, LogError<F::Error>> {
        let per = Self::SLOTS_PER_SECTOR;
        let slots = self.slots();
        let start = self.newest.map_or(0, |i| (i + 1) % slots);
        let sector = if self.newest.is_some() && start.is_multiple_of(per) {
            // The newest filled the last slot of its sector: on to the next sector.
            start / per
        } else {
            let end = (start / per + 1) * per;
            for i in start..end {
                if self.blank(i, 1)? {
                    return Ok(i);
                }
            }
            // Every slot left in this sector was written (uncommitted ones included).
            (start / per + 1) % self.region.sectors
        };
        let first = sector * per;
        if !self.blank(first, per)? {
            if self.newest.is_some_and(|i| i / per == sector) {
                // A single sector: the erase takes the only save with it.
                self.newest = None;
            }
            let from = Self::offset(self.region, first);
            let to = from + F::ERASE_SIZE as u32;
            self.flash.erase(from, to).map_err(LogError::Flash)?;
        }
        Ok(first)
    }

    /// Whether `count` slots from `first` are all erased.
    fn blank(&mut self, first: u32, count: u32) -> Result<bool, LogError<F::Error>> {
        let mut chunk = [0u8; CHUNK];
        let from = Self::offset(self.region, first);
        let len = count * SLOT as u32;
        let mut off = 0;
        while off < len {
            let n = (len - off).min(chunk.len() as u32);
            let part = chunk.get_mut(..n as usize).ok_or(LogError::Verify)?;
            self.flash.read(from + off, part).map_err(LogError::Flash)?;
            if part.iter().any(|&b| b != 0xFF) {
                return Ok(false);
            }
            off += n;
        }
        Ok(true)
    }
}
