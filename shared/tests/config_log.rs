//! The configuration log (`pen_io::config_log`) against an in-memory NOR flash that enforces
//! NOR rules (erase sets `0xFF`, a write that would set a bit is a bug: the model panics)
//! and can lose power after any number of bytes of any write or erase, leaving the byte it
//! was working on half done. After every power loss the log is reopened as at boot and must
//! load the save that was in progress or the one before it: never an older one, never
//! garbage. Damaged, erased and foreign flash give the handshake's `ConfigState`.

use maobi_shared::kinematics::RawReadings;
use maobi_shared::pen_io::config_log::{committed, trailer, TRAILER_LEN};
use maobi_shared::pen_io::nor_flash::{
    check_erase, check_read, check_write, ErrorType, NorFlash, NorFlashError, NorFlashErrorKind,
    ReadNorFlash,
};
use maobi_shared::pen_io::*;
use maobi_shared::protocol::crc32;
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------
// The flash model

#[derive(Copy, Clone, Debug, PartialEq, Eq)]
enum NorError {
    /// The power went during this operation, or before it.
    PowerLost,
    Kind(NorFlashErrorKind),
}

impl NorFlashError for NorError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            NorError::PowerLost => NorFlashErrorKind::Other,
            NorError::Kind(k) => *k,
        }
    }
}

/// NOR flash of `SECTOR`-byte erase sectors, programmed in 4-byte words (the STM32F411's
/// `WRITE_SIZE` in embassy-stm32).
struct Nor<const SECTOR: usize> {
    bytes: Vec<u8>,
    /// Bytes that may still be programmed or erased before the power goes (`None`: no cut).
    budget: Option<usize>,
    /// Bits left at 1 in the byte the power cut interrupts (programming) or left at 0
    /// (erasing): a half-done cell.
    tear_noise: u8,
    /// Erase from the sector's end to its start (the order a chip erases in is not
    /// specified; both are tried).
    erase_backwards: bool,
    /// The power is gone: every operation fails until `power_on`.
    dead: bool,
    /// A worn cell: bit 0 of this byte never programs (reads back 1).
    stuck: Option<usize>,
    erases: usize,
}

impl<const SECTOR: usize> Nor<SECTOR> {
    fn erased(sectors: usize) -> Self {
        Nor {
            bytes: vec![0xFF; sectors * SECTOR],
            budget: None,
            tear_noise: 0,
            erase_backwards: false,
            dead: false,
            stuck: None,
            erases: 0,
        }
    }

    /// The power goes after `bytes` more bytes are changed, the last one half done.
    fn cut_after(&mut self, bytes: usize, noise: u8) {
        self.budget = Some(bytes);
        self.tear_noise = noise;
    }

    fn power_on(&mut self) {
        self.dead = false;
        self.budget = None;
    }

    /// One more byte may change; false (and the power gone) when the budget is used up.
    fn spend(&mut self) -> bool {
        match &mut self.budget {
            Some(0) => {
                self.dead = true;
                false
            }
            Some(n) => {
                *n -= 1;
                true
            }
            None => true,
        }
    }
}

impl<const SECTOR: usize> ErrorType for Nor<SECTOR> {
    type Error = NorError;
}

impl<const SECTOR: usize> ReadNorFlash for Nor<SECTOR> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, out: &mut [u8]) -> Result<(), NorError> {
        if self.dead {
            return Err(NorError::PowerLost);
        }
        check_read(self, offset, out.len()).map_err(NorError::Kind)?;
        let o = offset as usize;
        out.copy_from_slice(&self.bytes[o..o + out.len()]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.bytes.len()
    }
}

impl<const SECTOR: usize> NorFlash for Nor<SECTOR> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = SECTOR;

    fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), NorError> {
        if self.dead {
            return Err(NorError::PowerLost);
        }
        check_write(self, offset, data.len()).map_err(NorError::Kind)?;
        for (i, &v) in data.iter().enumerate() {
            let at = offset as usize + i;
            let old = self.bytes[at];
            assert_eq!(
                v & !old,
                0,
                "NOR rule broken: writing {v:#04x} over {old:#04x} at {at:#x} would set bits"
            );
            if !self.spend() {
                // Half programmed: some of the bits to clear are still 1.
                self.bytes[at] = old & (v | self.tear_noise);
                return Err(NorError::PowerLost);
            }
            let worn = if self.stuck == Some(at) { 1 } else { 0 };
            self.bytes[at] = old & (v | worn);
        }
        Ok(())
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), NorError> {
        if self.dead {
            return Err(NorError::PowerLost);
        }
        check_erase(self, from, to).map_err(NorError::Kind)?;
        self.erases += 1;
        let range: Vec<usize> = if self.erase_backwards {
            (from as usize..to as usize).rev().collect()
        } else {
            (from as usize..to as usize).collect()
        };
        for at in range {
            if !self.spend() {
                // Half erased: some bits are back at 1.
                self.bytes[at] |= self.tear_noise;
                return Err(NorError::PowerLost);
            }
            self.bytes[at] = 0xFF;
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------
// Helpers

/// Small sectors in the tests (four 512-byte slots each) so that the log wraps often.
const SECTOR: usize = 2048;
const SLOT: usize = 512;
type Log = ConfigLog<Nor<SECTOR>, SLOT>;

fn region(sectors: u32) -> Region {
    Region::new::<Nor<SECTOR>, SLOT>(0, sectors)
}

/// The `n`-th configuration saved: each one different (its calibration's first encoder
/// count is `n`), of varying image length.
fn config(n: u32) -> DeviceConfig {
    let mut c = DeviceConfig::DEFAULT;
    c.calibration = Some(RawReadings {
        encoders: [i64::from(n) * 1_000_003, -7, 3],
        gimbal: [2048, 2047, (n % 4096) as i32],
    });
    c
}

fn image(cfg: &DeviceConfig) -> Vec<u8> {
    let mut buf = vec![0u8; CONFIG_IMAGE_MAX];
    let n = encode(cfg, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

/// What the log loads, decoded (as the link task does at boot).
fn loaded(log: &mut Log) -> Result<DeviceConfig, ConfigError> {
    let mut buf = [0u8; CONFIG_IMAGE_MAX];
    let n = log.load(&mut buf);
    decode(&buf[..n])
}

/// A power cycle: the log is dropped and reopened over the same flash.
fn reboot(log: Log, sectors: u32) -> Log {
    let mut flash = log.into_inner();
    flash.power_on();
    Log::open(flash, region(sectors))
}

// ---------------------------------------------------------------------------------------
// The model itself

#[test]
#[should_panic(expected = "NOR rule broken")]
fn the_model_refuses_to_set_a_bit() {
    let mut f = Nor::<SECTOR>::erased(1);
    f.write(0, &[0x0F, 0, 0, 0]).unwrap();
    let _ = f.write(0, &[0xF0, 0, 0, 0]);
}

#[test]
fn the_model_tears_writes_and_erases() {
    let mut f = Nor::<SECTOR>::erased(1);
    f.cut_after(5, 0x81);
    assert_eq!(f.write(0, &[0; 8]), Err(NorError::PowerLost));
    assert_eq!(&f.bytes[..8], &[0, 0, 0, 0, 0, 0x81, 0xFF, 0xFF]);
    assert_eq!(f.read(0, &mut [0; 4]), Err(NorError::PowerLost));
    f.power_on();
    f.cut_after(3, 0x01);
    assert_eq!(f.erase(0, SECTOR as u32), Err(NorError::PowerLost));
    assert_eq!(&f.bytes[..6], &[0xFF, 0xFF, 0xFF, 0x01, 0, 0x81]);
    // Misaligned writes are refused as the F411's driver refuses them.
    f.power_on();
    assert!(f.write(1, &[0; 4]).is_err());
    assert!(f.write(0, &[0; 3]).is_err());
}

#[test]
fn a_trailer_moved_any_bit_either_way_is_not_a_commit() {
    for seq in [1u32, 2, 0x0102_0304, 0x7FFF_FFFF, u32::MAX - 1, u32::MAX] {
        let t = trailer(seq);
        assert_eq!(committed(t), Some(seq));
        for bit in 0..8 * TRAILER_LEN {
            let (byte, mask) = (bit / 8, 1u8 << (bit % 8));
            let mut up = t;
            up[byte] |= mask;
            let mut down = t;
            down[byte] &= !mask;
            // The bit was already there (or not): the trailer did not change.
            if up != t {
                assert_eq!(committed(up), None, "seq {seq:#x}, bit {bit} set");
            }
            if down != t {
                assert_eq!(committed(down), None, "seq {seq:#x}, bit {bit} cleared");
            }
        }
    }
    // Erased and zeroed trailers are not commits.
    assert_eq!(committed([0xFF; TRAILER_LEN]), None);
    assert_eq!(committed([0; TRAILER_LEN]), None);
    // Nor is a sequence number programmed without its complement (why `seq` starts at 1).
    let mut half = [0xFF; TRAILER_LEN];
    half[..4].copy_from_slice(&0u32.to_le_bytes());
    assert_eq!(committed(half), None);
}

// ---------------------------------------------------------------------------------------
// Saving and loading

#[test]
fn an_erased_region_is_missing() {
    for sectors in [1, 2] {
        let mut log = Log::open(Nor::erased(sectors as usize), region(sectors));
        assert_eq!(log.newest_slot(), None);
        assert_eq!(loaded(&mut log), Err(ConfigError::Erased));
        assert_eq!(
            ConfigState::of(&loaded(&mut log)),
            ConfigState::Missing,
            "{sectors} sectors"
        );
    }
}

#[test]
fn every_save_loads_back_across_many_wraps() {
    for sectors in [1u32, 2, 3] {
        let mut log = Log::open(Nor::erased(sectors as usize), region(sectors));
        let slots = log.slots();
        for n in 0..(slots * 5 + 3) {
            log.store(&image(&config(n))).unwrap();
            assert_eq!(
                loaded(&mut log),
                Ok(config(n)),
                "{sectors} sectors, save {n}"
            );
            log = reboot(log, sectors);
            assert_eq!(
                log.newest_slot(),
                Some(n % slots),
                "{sectors} sectors, save {n}"
            );
            assert_eq!(
                loaded(&mut log),
                Ok(config(n)),
                "{sectors} sectors, save {n}"
            );
        }
        // One erase each time the log moves into a sector that was written before.
        let erases = log.into_inner().erases;
        let expected = (slots * 5 + 3 - 1) / (slots / sectors) + 1 - sectors;
        assert_eq!(erases as u32, expected, "{sectors} sectors");
    }
}

#[test]
fn the_black_pill_layout_wraps_its_two_sectors() {
    // Sectors 6 and 7 of the STM32F411CE, 512-byte slots (firmware/src/blackpill/config.rs).
    const BIG: usize = 128 * 1024;
    type PenLog = ConfigLog<Nor<BIG>, 512>;
    let region = Region::new::<Nor<BIG>, 512>(0, 2);
    let mut log = PenLog::open(Nor::erased(2), region);
    assert_eq!(log.slots(), 512);
    const { assert!(PenLog::IMAGE_ROOM >= CONFIG_IMAGE_MAX) };
    for n in 0..600 {
        log.store(&image(&config(n))).unwrap();
    }
    let mut flash = log.into_inner();
    assert_eq!(flash.erases, 1, "sector 0 erased once, at save 512");
    flash.power_on();
    let mut log = PenLog::open(flash, region);
    assert_eq!(log.newest_slot(), Some(599 % 512));
    let mut buf = [0u8; CONFIG_IMAGE_MAX];
    let k = log.load(&mut buf);
    assert_eq!(decode(&buf[..k]), Ok(config(599)));
}

#[test]
fn an_image_too_large_for_a_slot_is_refused() {
    let mut log = Log::open(Nor::erased(2), region(2));
    log.store(&image(&config(1))).unwrap();
    assert_eq!(
        log.store(&[0x55; SLOT - TRAILER_LEN + 1]),
        Err(LogError::TooLarge)
    );
    assert_eq!(loaded(&mut log), Ok(config(1)));
}

#[test]
fn a_failed_read_back_leaves_the_previous_save() {
    let mut log = Log::open(Nor::erased(2), region(2));
    log.store(&image(&config(1))).unwrap();
    // The next slot (1) has a worn cell in its image.
    let mut flash = log.into_inner();
    flash.stuck = Some(SLOT + 20);
    let mut log = Log::open(flash, region(2));
    assert_eq!(log.store(&image(&config(2))), Err(LogError::Verify));
    assert_eq!(loaded(&mut log), Ok(config(1)));
    let mut log = reboot(log, 2);
    assert_eq!(
        loaded(&mut log),
        Ok(config(1)),
        "the failed slot is not committed"
    );
    // The next save passes over the failed slot.
    log.store(&image(&config(3))).unwrap();
    assert_eq!(log.newest_slot(), Some(2));
    let mut log = reboot(log, 2);
    assert_eq!(loaded(&mut log), Ok(config(3)));
}

// ---------------------------------------------------------------------------------------
// Damaged and foreign flash

/// A region with saves 0..=n in it, the newest in slot `n`, and the flash.
fn with_saves(n: u32) -> Nor<SECTOR> {
    let mut log = Log::open(Nor::erased(2), region(2));
    for k in 0..=n {
        log.store(&image(&config(k))).unwrap();
    }
    log.into_inner()
}

#[test]
fn a_damaged_newest_save_is_corrupt_not_replaced_by_an_older_one() {
    let len = image(&config(2)).len();
    for bit in [0usize, 7, 8 * 9 + 3, 8 * (len / 2), 8 * len - 1] {
        let mut flash = with_saves(2);
        flash.bytes[2 * SLOT + bit / 8] ^= 1 << (bit % 8);
        let mut log = Log::open(flash, region(2));
        let got = loaded(&mut log);
        assert!(
            matches!(
                ConfigState::of(&got),
                ConfigState::Corrupt(
                    ConfigError::CrcMismatch { .. }
                        | ConfigError::BadMagic
                        | ConfigError::UnsupportedVersion { .. }
                        | ConfigError::BadLength { .. }
                        | ConfigError::Truncated
                )
            ),
            "bit {bit}: {got:?}"
        );
        assert!(!ConfigState::of(&got).allows_forces());
    }
}

/// Overwrites slot `slot` with `bytes` and a committed trailer of sequence `seq` (as a
/// save would have, whatever its image).
fn commit_raw(flash: &mut Nor<SECTOR>, slot: usize, bytes: &[u8], seq: u32) {
    let at = slot * SLOT;
    flash.bytes[at..at + SLOT].fill(0xFF);
    flash.bytes[at..at + bytes.len()].copy_from_slice(bytes);
    let t = at + SLOT - TRAILER_LEN;
    flash.bytes[t..t + TRAILER_LEN].copy_from_slice(&trailer(seq));
}

#[test]
fn committed_but_unreadable_images_say_why() {
    let good = image(&config(5));
    let mut other_version = good.clone();
    other_version[4..6].copy_from_slice(&(CONFIG_FORMAT_VERSION + 1).to_le_bytes());
    let n = other_version.len() - 4;
    let crc = crc32(&other_version[..n]);
    other_version[n..].copy_from_slice(&crc.to_le_bytes());
    let cases: [(&str, Vec<u8>, ConfigState); 4] = [
        (
            "truncated",
            good[..good.len() - 10].to_vec(),
            ConfigState::Corrupt(ConfigError::Truncated),
        ),
        (
            "other version",
            other_version,
            ConfigState::Corrupt(ConfigError::UnsupportedVersion {
                found: CONFIG_FORMAT_VERSION + 1,
            }),
        ),
        (
            "not an image",
            b"hello, flash".to_vec(),
            ConfigState::Corrupt(ConfigError::BadMagic),
        ),
        // A committed slot whose image is blank: nothing usable, said as missing.
        ("blank image", Vec::new(), ConfigState::Missing),
    ];
    for (name, bytes, want) in cases {
        let mut flash = with_saves(1);
        commit_raw(&mut flash, 2, &bytes, 3);
        let mut log = Log::open(flash, region(2));
        assert_eq!(log.newest_slot(), Some(2), "{name}");
        assert_eq!(ConfigState::of(&loaded(&mut log)), want, "{name}");
    }
}

#[test]
fn flash_without_a_committed_slot_is_missing() {
    // Garbage everywhere (another firmware's data, say) but no matching trailer: nothing
    // stored.
    let mut flash = Nor::<SECTOR>::erased(2);
    let mut x = 0x1234_5678u32;
    for b in flash.bytes.iter_mut() {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        *b = x as u8;
    }
    let mut log = Log::open(flash, region(2));
    assert_eq!(ConfigState::of(&loaded(&mut log)), ConfigState::Missing);
    // A save erases what it needs and works.
    log.store(&image(&config(9))).unwrap();
    let mut log = reboot(log, 2);
    assert_eq!(loaded(&mut log), Ok(config(9)));
}

/// Flash another firmware left behind: pseudo-random bytes in every sector.
fn foreign(sectors: usize) -> Nor<SECTOR> {
    let mut flash = Nor::<SECTOR>::erased(sectors);
    let mut x = 0x9E37_79B9u32;
    for b in flash.bytes.iter_mut() {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        *b = x as u8;
    }
    flash
}

#[test]
fn reclaiming_foreign_flash_at_boot_spares_the_first_save_its_erase() {
    // Without it: the first save pays an erase (the stall on the host's first `set`).
    let mut log = Log::open(foreign(2), region(2));
    log.store(&image(&config(1))).unwrap();
    assert_eq!(log.into_inner().erases, 1);
    // With it: the erases happen at boot, the first saves erase nothing.
    let mut log = Log::open(foreign(2), region(2));
    assert_eq!(log.reclaim(&CONFIG_MAGIC), Ok(2));
    assert_eq!(ConfigState::of(&loaded(&mut log)), ConfigState::Missing);
    let erased_at_boot = 2;
    for k in 0..4 {
        log.store(&image(&config(k))).unwrap();
    }
    let mut log = reboot(log, 2);
    assert_eq!(loaded(&mut log), Ok(config(3)));
    // Reclaiming again finds the log's own saves and leaves them.
    assert_eq!(log.reclaim(&CONFIG_MAGIC), Ok(0));
    assert_eq!(loaded(&mut log), Ok(config(3)));
    assert_eq!(log.into_inner().erases, erased_at_boot);
}

#[test]
fn reclaim_keeps_saves_and_blank_flash_and_takes_what_is_not_ours() {
    // An erased region: nothing to do.
    let mut log = Log::open(Nor::erased(2), region(2));
    assert_eq!(log.reclaim(&CONFIG_MAGIC), Ok(0));
    assert_eq!(log.into_inner().erases, 0);
    // The log's saves, in either sector, and an image of another format version (ours:
    // reported as such, not erased).
    for n in [0, 5] {
        let mut log = Log::open(with_saves(n), region(2));
        assert_eq!(log.reclaim(&CONFIG_MAGIC), Ok(0), "{n}");
        assert_eq!(loaded(&mut log), Ok(config(n)));
    }
    let mut other_version = image(&config(2));
    other_version[4..6].copy_from_slice(&(CONFIG_FORMAT_VERSION + 1).to_le_bytes());
    let mut flash = with_saves(1);
    commit_raw(&mut flash, 2, &other_version, 3);
    let mut log = Log::open(flash, region(2));
    assert_eq!(log.reclaim(&CONFIG_MAGIC), Ok(0));
    assert!(matches!(
        ConfigState::of(&loaded(&mut log)),
        ConfigState::Corrupt(ConfigError::UnsupportedVersion { .. })
    ));
    // A committed slot that is not a configuration image (foreign bytes whose trailer
    // happens to match): not ours, taken over.
    let mut flash = foreign(2);
    commit_raw(&mut flash, 5, b"demo firmware data", 77);
    let mut log = Log::open(flash, region(2));
    assert_eq!(log.newest_slot(), Some(5));
    assert_eq!(log.reclaim(&CONFIG_MAGIC), Ok(2));
    assert_eq!(log.newest_slot(), None);
    assert_eq!(ConfigState::of(&loaded(&mut log)), ConfigState::Missing);
    // Only what is not blank is erased: a first save cut short in sector 0.
    let mut flash = Nor::<SECTOR>::erased(2);
    flash.bytes[..100].fill(0x42);
    let mut log = Log::open(flash, region(2));
    assert_eq!(log.reclaim(&CONFIG_MAGIC), Ok(1));
    log.store(&image(&config(4))).unwrap();
    let mut log = reboot(log, 2);
    assert_eq!(loaded(&mut log), Ok(config(4)));
    assert_eq!(log.into_inner().erases, 1);
}

#[test]
fn the_sequence_number_not_the_position_says_which_is_newest() {
    // An interrupted erase left an older save behind, later in the sector than the newest.
    // Saves 0..=3 fill sector 0, 4 and 5 are in slots 4 and 5 of sector 1; slot 7 gets an
    // older committed save.
    let mut flash = with_saves(5);
    commit_raw(&mut flash, 7, &image(&config(1)), 1);
    let mut log = Log::open(flash, region(2));
    assert_eq!(log.newest_slot(), Some(5));
    assert_eq!(loaded(&mut log), Ok(config(5)));
}

// ---------------------------------------------------------------------------------------
// Power loss anywhere

/// One step of a run: a save that completes, or one that loses the power after `cut`
/// bytes (of its erase, image and trailer together), leaving the cut byte half done with
/// `noise`.
#[derive(Clone, Debug)]
enum Step {
    Save,
    Torn { cut: usize, noise: u8 },
}

fn step() -> impl Strategy<Value = Step> {
    prop_oneof![
        2 => Just(Step::Save),
        3 => (0usize..SECTOR + SLOT, any::<u8>()).prop_map(|(cut, noise)| Step::Torn { cut, noise }),
    ]
}

/// Runs `steps` on a log of `sectors` sectors, rebooting after every torn save, and checks
/// after each step what loads. Returns how many torn saves lost the save before them.
///
/// With two or more sectors a torn save leaves that save (if its commit got programmed) or
/// the one before. With one sector a torn erase may also leave an older complete save, or
/// nothing usable (missing, or the newest slot's half-erased image reported corrupt); never
/// a configuration that was not saved.
fn run(sectors: u32, backwards: bool, steps: &[Step]) -> Result<u32, TestCaseError> {
    let mut flash = Nor::<SECTOR>::erased(sectors as usize);
    flash.erase_backwards = backwards;
    let mut log = Log::open(flash, region(sectors));
    // What loads now: a save's number, or an error (`None`: missing or unusable).
    let mut current: Option<u32> = None;
    let mut saved_any = false;
    let mut lost = 0;
    for (n, s) in steps.iter().enumerate() {
        let n = n as u32;
        match s {
            Step::Save => {
                prop_assert_eq!(log.store(&image(&config(n))), Ok(()));
                current = Some(n);
                saved_any = true;
            }
            Step::Torn { cut, noise } => {
                let mut flash = log.into_inner();
                flash.cut_after(*cut, *noise);
                log = Log::open(flash, region(sectors));
                let result = log.store(&image(&config(n)));
                log = reboot(log, sectors);
                let got = loaded(&mut log);
                if result.is_ok() {
                    // The cut came after the last byte: the save is complete.
                    prop_assert_eq!(&got, &Ok(config(n)));
                }
                match (&got, current) {
                    // The save in progress: its commit was programmed before the cut. It is a
                    // save like any other: a later torn erase may leave its half-erased
                    // image behind, reported corrupt, not missing.
                    (Ok(c), _) if *c == config(n) => {
                        current = Some(n);
                        saved_any = true;
                    }
                    // The one before.
                    (Ok(c), Some(k)) if *c == config(k) => {}
                    (_, None) if !saved_any => {
                        prop_assert_eq!(ConfigState::of(&got), ConfigState::Missing);
                    }
                    _ => {
                        prop_assert!(sectors == 1, "{} sectors, cut {}: {:?}", sectors, cut, got);
                        lost += 1;
                        current = match &got {
                            Ok(c) => {
                                let k = (0..n).find(|&k| *c == config(k));
                                prop_assert!(k.is_some(), "never saved: {:?}", c);
                                k
                            }
                            Err(_) => {
                                prop_assert!(!ConfigState::of(&got).allows_forces());
                                None
                            }
                        };
                    }
                }
            }
        }
        // The log holds what we think, and so does the next boot.
        for _ in 0..2 {
            let got = loaded(&mut log);
            match current {
                Some(c) => prop_assert_eq!(&got, &Ok(config(c)), "after step {}", n),
                None => prop_assert!(got.is_err(), "after step {}: {:?}", n, got),
            }
            log = reboot(log, sectors);
        }
    }
    Ok(lost)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, .. ProptestConfig::default() })]

    #[test]
    fn power_loss_leaves_the_save_in_progress_or_the_one_before(
        sectors in 2u32..=3,
        backwards in any::<bool>(),
        steps in proptest::collection::vec(step(), 1..40),
    ) {
        run(sectors, backwards, &steps)?;
    }

    #[test]
    fn a_single_sector_loses_saves_only_to_an_erase_and_never_to_garbage(
        backwards in any::<bool>(),
        steps in proptest::collection::vec(step(), 1..40),
    ) {
        run(1, backwards, &steps)?;
    }
}

/// Every cut point of the save that wraps into a written sector (the erase, the image,
/// the trailer), for both erase orders: with two sectors the previous save always
/// survives; with one, a cut in the erase or the save after it loses it (and only then).
#[test]
fn every_cut_of_a_save_that_erases() {
    for sectors in [1u32, 2] {
        for backwards in [false, true] {
            let slots = sectors * (SECTOR / SLOT) as u32;
            let mut losses = 0;
            let len = image(&config(slots)).len().next_multiple_of(4) + TRAILER_LEN;
            for cut in 0..SECTOR + len {
                // `slots` saves fill the region; the next one erases.
                let mut steps = vec![Step::Save; slots as usize];
                steps.push(Step::Torn { cut, noise: 0x5A });
                losses += run(sectors, backwards, &steps).unwrap();
            }
            if sectors == 1 {
                // Lost once the erase reaches the newest slot (backwards: its trailer goes
                // first; forwards: after the three slots before it), and at every cut
                // between the erase and the new save's last byte.
                println!(
                    "one sector, backwards {backwards}: {losses} of {} cuts lose the save",
                    SECTOR + len
                );
                let from = if backwards { 0 } else { 3 * SLOT };
                assert!(losses as usize >= SECTOR - from + len - SLOT, "{backwards}");
            } else {
                assert_eq!(losses, 0);
            }
        }
    }
}
