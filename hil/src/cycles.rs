//! `hil bench`'s cycle estimate of the force-loop tick on the Black Pill (STM32F411CE,
//! Cortex-M4F at 96 MHz): the instructions QEMU executed for the default brush's ticks,
//! in order, weighted with the Cortex-M4's instruction timings and the F411's flash (3 wait
//! states behind the ART accelerator), plus the tick's blocking ADC reads and the worst
//! state fill. The model, its table and what it leaves out: `docs/firmware-cost.md`,
//! section "Cycles". This module is the model's only implementation.
//!
//! The instruction stream comes from QEMU's own log (`-d in_asm,exec,nochain`: each
//! translated block's disassembly once, then every executed block's address; Debian's QEMU
//! has no TCG plugins), read from a pipe as QEMU writes it, so that no log file is kept.
//! The firmware's `bench SHIFT cycles` mode brackets each tick and each state fill with
//! marker calls (`maobi_firmware::app::bench::trace_*`, found by name in the image).

use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};

use crate::qemu::{Clock, Run};

/// The Black Pill's core clock (`firmware/src/blackpill/mod.rs`, `SYSCLK_HZ`).
pub const SYSCLK_HZ: u64 = 96_000_000;
/// The force loop's rate.
pub const TICK_HZ: u64 = 1000;
/// The goal: 80% of the cycles of one tick.
pub const GOAL_CYCLES: u64 = SYSCLK_HZ / TICK_HZ * 80 / 100;
/// Flash wait states at 96 MHz and 3.3 V (RM0383, "Relation between CPU clock frequency and
/// Flash memory read time"): what an access that the ART cannot serve costs on top.
pub const WAIT_STATES: u32 = 3;
/// The ART's line: 128 bits.
pub const LINE_BYTES: u32 = 16;
/// The ART's instruction cache: 64 lines (1 KiB).
pub const ICACHE_LINES: usize = 64;
/// The ART's data cache (literal pools read from flash): 8 lines.
pub const DCACHE_LINES: usize = 8;
/// SDIV/UDIV take 2-12 cycles by their operands, which the log does not give: the worst.
pub const DIVIDE_CYCLES: u32 = 12;

/// The Black Pill's gimbal reads (`firmware/src/blackpill/sensors.rs`): three channels,
/// one injected scan per tick at 84 sample cycles each.
pub const ADC_CHANNELS: u64 = 3;
pub const ADC_SAMPLE_CYCLES: u64 = 84;
/// A 12-bit conversion's own ADC cycles after the sample time (RM0383).
pub const ADC_CONVERSION_CYCLES: u64 = 12;
/// ADC clock = PCLK2 (96 MHz) / 4: embassy's prescaler choice for the 36 MHz limit.
pub const ADC_PRESCALER: u64 = 4;

/// What an instruction costs, before branches and the flash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A fixed number of cycles (data processing 1, multiplies 1, LDRD/STRD 3, LDM/STM/PUSH/POP
    /// 1+N, VLDR 2 or 3, VDIV/VSQRT 14, ...).
    Fixed(u32),
    /// A single load (LDR, LDRB, LDRH, LDRSB, LDRSH): 2, or 1 right after another single
    /// load whose result its address does not use (the address and data phases pipeline).
    Load,
    /// A single store: 1 with an immediate offset (its data phase overlaps the next
    /// instruction); 2 with a register offset, 1 right after a single load (as a load).
    Store { imm: bool },
    /// Not in the model's table: counted as 1 cycle and reported.
    Unknown,
}

/// One instruction of QEMU's disassembly.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Insn {
    pub addr: u32,
    /// 2 or 4 bytes.
    pub size: u8,
    pub kind: Kind,
    /// It may write the PC (a branch, or a pop, load or move into the PC).
    pub branch: Option<Branch>,
    /// A PC-relative load from flash (a literal pool): its address and bytes.
    pub literal: Option<(u32, u32)>,
    /// Registers (bit n: Rn) a data-processing instruction writes, or a single load loads.
    pub writes: u16,
    /// Registers a load or store forms its address from.
    pub addr_regs: u16,
}

impl Insn {
    /// An instruction of `kind` that neither branches nor touches memory or registers the
    /// model tracks.
    pub fn plain(addr: u32, size: u8, kind: Kind) -> Self {
        Insn {
            addr,
            size,
            kind,
            branch: None,
            literal: None,
            writes: 0,
            addr_regs: 0,
        }
    }
}

/// Where a branch's target comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Branch {
    /// An immediate (B, BL, CBZ): the core fetches the target early.
    Direct,
    /// A register (BX, BLX Rm, MOV PC): known at execute.
    Register,
    /// Memory (POP/LDM/LDR into the PC, TBB/TBH): "a blocking operation", the TRM's full
    /// pipeline reload.
    Memory,
}

/// The pipeline refill of a taken branch, P in the TRM's table (1 to 3): 1 for a direct
/// branch, 2 for a register's target, 3 for a target loaded from memory; 1 more (at most 3)
/// when the target is a 32-bit instruction that is not word-aligned (two fetches).
pub fn refill(from: Branch, target_wide_unaligned: bool) -> u32 {
    let base = match from {
        Branch::Direct => 1,
        Branch::Register => 2,
        Branch::Memory => 3,
    };
    (base + u32::from(target_wide_unaligned)).min(3)
}

/// What the instruction before the one being timed left in the pipeline.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Prev {
    /// Registers it wrote as a data-processing result.
    pub alu_writes: u16,
    /// It was a single load, into these registers.
    pub load_dest: Option<u16>,
}

/// The core's cycles for `insn` (no flash stalls): its [`Kind`]; 1 less for a single load
/// or register-offset store pipelined after a single load (not when its address uses what
/// that load loaded); 1 more for a load or store whose address uses the result of the
/// data-processing instruction before it (no forwarding path, says the TRM); plus the
/// refill `p` when it branched.
pub fn core_cycles(insn: &Insn, taken: bool, p: u32, prev: Prev) -> u32 {
    let pipelined = prev.load_dest.is_some_and(|d| d & insn.addr_regs == 0);
    let base = match insn.kind {
        Kind::Fixed(n) => n,
        Kind::Unknown => 1,
        Kind::Load | Kind::Store { imm: false } => 2 - u32::from(pipelined),
        Kind::Store { imm: true } => 1,
    };
    let address_stall = u32::from(insn.addr_regs & prev.alu_writes != 0);
    base + address_stall + if taken { p } else { 0 }
}

/// Cycles and what they came from, for a stretch of the trace.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Cost {
    pub instructions: u64,
    /// The core's cycles ([`core_cycles`]).
    pub core: u64,
    /// Flash wait states the ART did not hide.
    pub flash_stalls: u64,
    pub taken_branches: u64,
    /// The refills (P) of those branches, summed: the part of `core` the TRM gives only as
    /// a range (1 to 3 each).
    pub refill: u64,
    /// Instruction lines fetched from flash (I-cache misses not covered by prefetch).
    pub icache_misses: u64,
    /// Literal-pool lines read from flash (D-cache misses).
    pub dcache_misses: u64,
    /// Instructions the table does not know (counted as 1 cycle each).
    pub unknown: u64,
}

impl Cost {
    pub fn cycles(&self) -> u64 {
        self.core + self.flash_stalls
    }
    /// [`Cost::cycles`] with every taken branch's refill at the TRM's least (1) and most (3).
    pub fn refill_range(&self) -> (u64, u64) {
        let c = self.cycles();
        (
            c - (self.refill - self.taken_branches),
            c + (3 * self.taken_branches - self.refill),
        )
    }
    fn add(&mut self, o: &Cost) {
        self.instructions += o.instructions;
        self.core += o.core;
        self.flash_stalls += o.flash_stalls;
        self.taken_branches += o.taken_branches;
        self.refill += o.refill;
        self.icache_misses += o.icache_misses;
        self.dcache_misses += o.dcache_misses;
        self.unknown += o.unknown;
    }
}

/// A fully associative cache of `cap` lines, least recently used out first (RM0383 gives
/// the ART's sizes, not its replacement: an assumption).
#[derive(Clone, Debug)]
struct Lru {
    lines: Vec<u32>,
    cap: usize,
}

impl Lru {
    fn new(cap: usize) -> Self {
        Lru {
            lines: Vec::with_capacity(cap),
            cap,
        }
    }
    /// Whether `line` was cached; it is afterwards, as the most recent.
    fn access(&mut self, line: u32) -> bool {
        if let Some(i) = self.lines.iter().position(|&l| l == line) {
            self.lines.remove(i);
            self.lines.push(line);
            return true;
        }
        if self.lines.len() == self.cap {
            self.lines.remove(0);
        }
        self.lines.push(line);
        false
    }
}

/// The F411's flash interface (ART accelerator) as the model sees it.
#[derive(Clone, Debug)]
struct Art {
    icache: Lru,
    dcache: Lru,
    /// The instruction line being executed; the next one is in the prefetch buffer.
    current: Option<u32>,
}

impl Art {
    fn new() -> Self {
        Art {
            icache: Lru::new(ICACHE_LINES),
            dcache: Lru::new(DCACHE_LINES),
            current: None,
        }
    }

    /// Misses fetching the instruction at `addr`: a line other than the current one and the
    /// prefetched next one comes from the I-cache, or from flash (a miss, then cached).
    fn fetch(&mut self, addr: u32, size: u8) -> u64 {
        let first = addr / LINE_BYTES;
        let last = (addr + u32::from(size) - 1) / LINE_BYTES;
        let mut misses = 0;
        for line in first..=last {
            let current = self.current;
            self.current = Some(line);
            if current == Some(line) || current.map(|c| c + 1) == Some(line) {
                continue;
            }
            if !self.icache.access(line) {
                misses += 1;
            }
        }
        misses
    }

    /// Misses reading `bytes` of a literal at `addr` through the D-cache.
    fn literal(&mut self, addr: u32, bytes: u32) -> u64 {
        let first = addr / LINE_BYTES;
        let last = (addr + bytes.max(1) - 1) / LINE_BYTES;
        (first..=last).filter(|&l| !self.dcache.access(l)).count() as u64
    }
}

/// The core and its flash, fed the executed instructions in order.
#[derive(Clone, Debug)]
pub struct Machine {
    art: Art,
    prev: Prev,
}

impl Default for Machine {
    fn default() -> Self {
        Self::new()
    }
}

impl Machine {
    /// Empty caches.
    pub fn new() -> Self {
        Machine {
            art: Art::new(),
            prev: Prev::default(),
        }
    }

    /// One executed instruction; `next`: the address and size of the instruction executed
    /// after it (`None`: unknown, a branch counts as not taken).
    pub fn step(&mut self, insn: &Insn, next: Option<(u32, u8)>) -> Cost {
        let fallthrough = insn.addr + u32::from(insn.size);
        let taken = insn.branch.is_some() && next.is_some_and(|(a, _)| a != fallthrough);
        let p = match (insn.branch, next) {
            (Some(b), Some((a, size))) => refill(b, size == 4 && a % 4 == 2),
            _ => 0,
        };
        let core = core_cycles(insn, taken, p, self.prev);
        let single_load = insn.kind == Kind::Load && insn.branch.is_none();
        self.prev = Prev {
            alu_writes: if single_load { 0 } else { insn.writes },
            load_dest: single_load.then_some(insn.writes),
        };
        let icache_misses = self.art.fetch(insn.addr, insn.size);
        let dcache_misses = insn
            .literal
            .map_or(0, |(a, bytes)| self.art.literal(a, bytes));
        Cost {
            instructions: 1,
            core: u64::from(core),
            flash_stalls: (icache_misses + dcache_misses) * u64::from(WAIT_STATES),
            taken_branches: u64::from(taken),
            refill: if taken { u64::from(p) } else { 0 },
            icache_misses,
            dcache_misses,
            unknown: u64::from(insn.kind == Kind::Unknown),
        }
    }

    /// Runs `insns` (addresses in execution order, the last one's successor `then`).
    pub fn run(&mut self, insns: &[Insn], then: Option<(u32, u8)>) -> Cost {
        let mut total = Cost::default();
        for (i, insn) in insns.iter().enumerate() {
            let next = insns.get(i + 1).map(|n| (n.addr, n.size)).or(then);
            total.add(&self.step(insn, next));
        }
        total
    }
}

/// The tick's gimbal reads on the Black Pill, in core cycles: the injected scan of the three
/// channels, sample and conversion at the ADC clock, counted whole. The tick reads the
/// encoders and the buttons while it converts and then waits for its end, so those reads'
/// instructions are counted twice (in the stream and inside the scan): an estimate on the
/// high side by a few dozen cycles. The register accesses that start and read the scan are
/// not counted.
pub fn adc_cycles() -> u64 {
    ADC_CHANNELS * (ADC_SAMPLE_CYCLES + ADC_CONVERSION_CYCLES) * ADC_PRESCALER
}

const CONDITIONS: [&str; 17] = [
    "eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt", "le",
    "al",
];

/// How a mnemonic's base is timed.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Base {
    /// 1 cycle; takes an `s` suffix.
    Alu,
    /// Fixed cycles, no `s`.
    Fixed(u32),
    Load,
    Store,
    /// LDRD/STRD: 3.
    Pair,
    /// LDM/STM/PUSH/POP: 1+N.
    Multiple,
    /// VLDM/VSTM/VPUSH/VPOP: 1+N words.
    FpMultiple,
    /// VLDR/VSTR: 2 (single) or 3 (double).
    FpLoad,
    /// VMOV: 1, or 2 moving two core registers.
    FpMov,
    /// B, BL: a direct branch (1, +P taken).
    Branch,
    /// BX, BLX: 1+P, from a register unless the operand is an immediate.
    BranchReg,
    /// TBB, TBH: 3+P.
    Table,
}

fn base_of(name: &str) -> Option<Base> {
    use Base::*;
    Some(match name {
        "adc" | "add" | "addw" | "adr" | "and" | "asr" | "bfc" | "bfi" | "bic" | "clz" | "cmn"
        | "cmp" | "eor" | "lsl" | "lsr" | "mov" | "movw" | "movt" | "mvn" | "neg" | "orn"
        | "orr" | "rbit" | "rev" | "rev16" | "revsh" | "ror" | "rrx" | "rsb" | "sbc" | "sbfx"
        | "sub" | "subw" | "sxtb" | "sxth" | "sxtab" | "sxtah" | "teq" | "tst" | "ubfx"
        | "uxtb" | "uxth" | "uxtab" | "uxtah" | "ssat" | "usat" | "mul" | "mla" | "mls"
        | "umull" | "smull" | "umlal" | "smlal" | "umaal" | "smmul" | "smmla" | "smmls"
        | "smulbb" | "smulbt" | "smultb" | "smultt" | "smlabb" | "smlabt" | "smlatb" | "smlatt"
        | "smulwb" | "smulwt" | "smlawb" | "smlawt" | "qadd" | "qsub" | "sel" => Alu,
        "nop" | "dmb" | "dsb" | "isb" | "cpsid" | "cpsie" | "mrs" | "msr" | "sev" | "wfi"
        | "wfe" | "yield" | "bkpt" | "svc" | "udf" | "pld" => Fixed(1),
        "sdiv" | "udiv" => Fixed(DIVIDE_CYCLES),
        "ldrd" | "strd" => Pair,
        "ldrex" | "ldrexb" | "ldrexh" | "strex" | "strexb" | "strexh" => Fixed(2),
        "ldr" | "ldrb" | "ldrh" | "ldrsb" | "ldrsh" | "ldrt" | "ldrbt" | "ldrht" => Load,
        "str" | "strb" | "strh" | "strt" | "strbt" | "strht" => Store,
        "ldm" | "ldmia" | "ldmfd" | "ldmdb" | "stm" | "stmia" | "stmea" | "stmdb" | "stmfd"
        | "push" | "pop" => Multiple,
        "vadd" | "vsub" | "vmul" | "vnmul" | "vabs" | "vneg" | "vcmp" | "vcmpe" | "vcvt"
        | "vcvtr" | "vcvta" | "vcvtn" | "vcvtp" | "vcvtm" | "vmrs" | "vmsr" => Fixed(1),
        "vmla" | "vmls" | "vnmla" | "vnmls" | "vfma" | "vfms" | "vfnma" | "vfnms" => Fixed(3),
        "vdiv" | "vsqrt" => Fixed(14),
        "vldr" | "vstr" => FpLoad,
        "vldm" | "vldmia" | "vldmdb" | "vstm" | "vstmia" | "vstmdb" | "vpush" | "vpop" => {
            FpMultiple
        }
        "vmov" => FpMov,
        "b" | "bl" => Branch,
        "bx" | "blx" => BranchReg,
        "tbb" | "tbh" => Table,
        _ => return None,
    })
}

/// Splits a mnemonic (no `.w`, no data type) into its base and whether a condition suffix
/// was present, trying the longest base first: `bls` is `b` + `ls`, `bics` is `bic` + `s`.
fn split_mnemonic(m: &str) -> Option<(Base, &str, bool)> {
    if m.starts_with("it") && m[2..].chars().all(|c| c == 't' || c == 'e') && m.len() <= 5 {
        return Some((Base::Fixed(1), "it", false));
    }
    for len in (1..=m.len()).rev() {
        let (name, rest) = m.split_at(len);
        let Some(base) = base_of(name) else { continue };
        let flags_ok = base == Base::Alu;
        let rest = match rest.strip_prefix('s') {
            Some(r) if flags_ok => r,
            _ => rest,
        };
        if rest.is_empty() {
            return Some((base, name, false));
        }
        if CONDITIONS.contains(&rest) {
            return Some((base, name, true));
        }
    }
    None
}

/// Registers in a `{...}` list (ranges `r4-r7` counted out), as 32-bit words for VFP lists
/// (a `d` register is two).
fn list_words(ops: &str) -> Option<(u32, bool)> {
    let inner = ops.split_once('{')?.1.split_once('}')?.0;
    let mut n = 0;
    let mut pc = false;
    for item in inner.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let width = if item.starts_with('d') { 2 } else { 1 };
        let count = match item.split_once('-') {
            Some((a, b)) => {
                fn num(s: &str) -> Result<u32, std::num::ParseIntError> {
                    s.trim_start_matches(|c: char| c.is_ascii_alphabetic())
                        .parse()
                }
                match (num(a), num(b)) {
                    (Ok(x), Ok(y)) if y >= x => y - x + 1,
                    _ => 1,
                }
            }
            None => 1,
        };
        pc |= item == "pc";
        n += width * count;
    }
    Some((n, pc))
}

/// Parses an immediate `#0x48`, `#-0x10` or `#72`.
fn imm(s: &str) -> Option<i64> {
    let s = s.trim().strip_prefix('#')?;
    let (neg, s) = match s.strip_prefix('-') {
        Some(r) => (true, r),
        None => (false, s),
    };
    let v = match s.strip_prefix("0x") {
        Some(h) => i64::from_str_radix(h, 16).ok()?,
        None => s.parse().ok()?,
    };
    Some(if neg { -v } else { v })
}

/// A core register's bit (`r0`-`r12`, `sb`, `sl`, `fp`, `ip`, `sp`, `lr`, `pc`; a trailing
/// `!` of write-back ignored), or 0 for anything else.
fn reg_bit(op: &str) -> u16 {
    let op = op.trim().trim_end_matches('!');
    let n = match op {
        "sb" => 9,
        "sl" => 10,
        "fp" => 11,
        "ip" => 12,
        "sp" => 13,
        "lr" => 14,
        "pc" => 15,
        _ => match op.strip_prefix('r').and_then(|n| n.parse::<u16>().ok()) {
            Some(n) if n < 16 => n,
            _ => return 0,
        },
    };
    1 << n
}

/// One line of QEMU's `in_asm` log (`0x00000404:  4812       ldr      r0, [pc, #0x48]`);
/// `None` for any other line.
pub fn decode(line: &str) -> Option<Insn> {
    let (addr, rest) = line.strip_prefix("0x")?.split_once(':')?;
    let addr = u32::from_str_radix(addr, 16).ok()?;
    let word = |s: &str| -> Option<(String, String)> {
        let s = s.trim_start();
        let (w, rest) = s.split_once(char::is_whitespace).unwrap_or((s, ""));
        Some((w.to_string(), rest.to_string())).filter(|(w, _)| !w.is_empty())
    };
    let (first, rest) = word(rest)?;
    let first = u16::from_str_radix(&first, 16).ok()?;
    // Thumb-2: a first halfword 0b11101, 0b11110 or 0b11111 starts a 32-bit instruction.
    let wide = first >> 11 >= 0b11101;
    let rest = if wide { word(&rest)?.1 } else { rest };
    let (mnemonic, ops) = word(&rest)?;
    let mnemonic = mnemonic.to_ascii_lowercase();
    let ops = ops.trim().to_ascii_lowercase();
    let head = mnemonic.split('.').next().unwrap_or("");
    let size = if wide { 4 } else { 2 };
    let mut branch = None;
    let mut literal = None;
    let mut writes = 0;
    let mut addr_regs = 0;
    let mut operands = ops.split(',').map(str::trim);
    let first_op = operands.next().unwrap_or("");
    let second_op = operands.next().unwrap_or("");
    let kind = match split_mnemonic(head) {
        None => Kind::Unknown,
        Some((base, name, _cond)) => match base {
            Base::Alu | Base::Fixed(_) => {
                if matches!(name, "mov" | "add") && first_op == "pc" {
                    branch = Some(Branch::Register);
                }
                if base == Base::Alu {
                    writes = match name {
                        "cmp" | "cmn" | "tst" | "teq" => 0,
                        "umull" | "smull" | "umlal" | "smlal" | "umaal" => {
                            reg_bit(first_op) | reg_bit(second_op)
                        }
                        _ => reg_bit(first_op),
                    };
                }
                match base {
                    Base::Fixed(n) => Kind::Fixed(n),
                    _ => Kind::Fixed(1),
                }
            }
            Base::Load | Base::Store | Base::Pair | Base::FpLoad => {
                let bytes = match name {
                    "ldrb" | "ldrsb" | "strb" => 1,
                    "ldrh" | "ldrsh" | "strh" => 2,
                    "ldrd" | "strd" => 8,
                    _ if base == Base::FpLoad && first_op.starts_with('d') => 8,
                    _ => 4,
                };
                let bracket = ops.split_once('[').map(|(_, b)| b).unwrap_or("");
                let inside = bracket.split_once(']').map(|(a, _)| a).unwrap_or("");
                let mut parts = inside.split(',').map(str::trim);
                let reg = parts.next().unwrap_or("");
                let offset = parts.next();
                addr_regs = reg_bit(reg) | offset.map_or(0, reg_bit);
                if base == Base::Load {
                    writes = reg_bit(first_op);
                }
                if reg == "pc" {
                    let off = offset.and_then(imm).unwrap_or(0);
                    let at = ((i64::from(addr) + 4) & !3) + off;
                    literal = u32::try_from(at).ok().map(|a| (a, bytes));
                }
                if base == Base::Load && first_op == "pc" {
                    branch = Some(Branch::Memory);
                }
                match base {
                    Base::Load => Kind::Load,
                    Base::Store => Kind::Store {
                        imm: offset.is_none_or(|o| o.starts_with('#')),
                    },
                    // LDRD/STRD and a double VLDR/VSTR: 3; a single VLDR/VSTR: 2.
                    _ => Kind::Fixed(if bytes == 8 { 3 } else { 2 }),
                }
            }
            Base::Multiple => match list_words(&ops) {
                Some((n, pc)) => {
                    addr_regs = if matches!(name, "push" | "pop") {
                        reg_bit("sp")
                    } else {
                        reg_bit(first_op)
                    };
                    if pc {
                        branch = Some(Branch::Memory);
                    }
                    Kind::Fixed(1 + n)
                }
                None => Kind::Unknown,
            },
            Base::FpMultiple => {
                addr_regs = if matches!(name, "vpush" | "vpop") {
                    reg_bit("sp")
                } else {
                    reg_bit(first_op)
                };
                list_words(&ops).map_or(Kind::Unknown, |(n, _)| Kind::Fixed(1 + n))
            }
            Base::FpMov => {
                let fp_reg = |o: &str| {
                    o.len() > 1
                        && (o.starts_with('s') || o.starts_with('d'))
                        && o[1..].bytes().all(|b| b.is_ascii_digit())
                };
                let core_regs = ops
                    .split(',')
                    .map(str::trim)
                    .filter(|o| !fp_reg(o) && !o.starts_with('#'))
                    .count();
                Kind::Fixed(if core_regs >= 2 { 2 } else { 1 })
            }
            Base::Branch => {
                branch = Some(Branch::Direct);
                Kind::Fixed(1)
            }
            Base::BranchReg => {
                branch = Some(if first_op.starts_with('#') {
                    Branch::Direct
                } else {
                    Branch::Register
                });
                Kind::Fixed(1)
            }
            Base::Table => {
                // The TRM's load/store notes: two cycles for the load, one for the add, and
                // the full pipeline reload (its table's 2 + P leaves the add out).
                addr_regs = ops
                    .split(',')
                    .take(2)
                    .map(|o| reg_bit(o.trim().trim_matches(['[', ']'])))
                    .fold(0, |a, b| a | b);
                branch = Some(Branch::Memory);
                Kind::Fixed(3)
            }
        },
    };
    // CBZ/CBNZ: not in the table's bases (their name ends like a condition).
    let kind = match (kind, head) {
        (Kind::Unknown, "cbz" | "cbnz") => {
            branch = Some(Branch::Direct);
            Kind::Fixed(1)
        }
        (k, _) => k,
    };
    Some(Insn {
        addr,
        size,
        kind,
        branch,
        literal,
        writes,
        addr_regs,
    })
}

/// The marker functions' entry addresses (`firmware/src/app/bench.rs`).
#[derive(Clone, Copy, Debug)]
pub struct Markers {
    pub tick_begin: u32,
    pub tick_end: u32,
    pub fill_begin: u32,
    pub fill_end: u32,
}

/// The image's functions, for charging cycles to them.
#[derive(Clone, Debug, Default)]
pub struct Symbols {
    /// (start, end, demangled name), sorted by start.
    funcs: Vec<(u32, u32, String)>,
}

impl Symbols {
    pub fn new(mut funcs: Vec<(u32, u32, String)>) -> Self {
        funcs.sort();
        Symbols { funcs }
    }
    /// The function holding `addr` (its index), or `len()` for none.
    fn index(&self, addr: u32) -> usize {
        let i = self.funcs.partition_point(|f| f.0 <= addr);
        match i.checked_sub(1) {
            Some(j) if addr < self.funcs[j].1 => j,
            _ => self.funcs.len(),
        }
    }
    fn name(&self, i: usize) -> &str {
        self.funcs.get(i).map_or("(no symbol)", |f| f.2.as_str())
    }
}

/// What the traced run gave.
#[derive(Clone, Debug)]
pub struct Traced {
    /// Each bracketed tick, in order.
    pub ticks: Vec<Cost>,
    /// Each bracketed state fill, in order.
    pub fills: Vec<Cost>,
    /// The dearest tick's cycles by function (the instruction's own function), dearest first.
    pub worst_tick_functions: Vec<(String, u64)>,
}

impl Traced {
    /// The dearest tick: its index (0-based) and cost.
    pub fn worst_tick(&self) -> Option<(usize, Cost)> {
        self.ticks
            .iter()
            .copied()
            .enumerate()
            .max_by_key(|(i, c)| (c.cycles(), std::cmp::Reverse(*i)))
    }
    pub fn worst_fill(&self) -> Option<Cost> {
        self.fills.iter().copied().max_by_key(Cost::cycles)
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Region {
    Tick,
    Fill,
}

/// Reads QEMU's `-d in_asm,exec,nochain` log and weighs every executed instruction with one
/// [`Machine`] (its caches carry over from everything that ran, bracketed or not), charging
/// those between the markers.
pub fn weigh_log(log: impl BufRead, markers: Markers, symbols: &Symbols) -> Result<Traced> {
    struct Tb {
        insns: Vec<Insn>,
        func: usize,
    }
    let mut tbs: Vec<Tb> = Vec::new();
    let mut by_host: HashMap<u64, usize> = HashMap::new();
    let mut block: Option<Vec<Insn>> = None;
    let mut machine = Machine::new();
    let mut region: Option<Region> = None;
    let mut prev: Option<(usize, Option<Region>)> = None;
    let mut out = Traced {
        ticks: vec![],
        fills: vec![],
        worst_tick_functions: vec![],
    };
    let mut per_fn = vec![0u64; symbols.funcs.len() + 1];
    let mut worst_fn: Vec<u64> = vec![];
    let mut worst_cycles = 0;
    let mut log = log;
    let mut line = String::new();
    loop {
        line.clear();
        if log.read_line(&mut line).context("reading QEMU's log")? == 0 {
            break;
        }
        if line.starts_with("IN:") {
            block = Some(Vec::new());
            continue;
        }
        if line.starts_with("0x") {
            if let (Some(b), Some(i)) = (block.as_mut(), decode(&line)) {
                b.push(i);
            }
            continue;
        }
        let Some(rest) = line.strip_prefix("Trace ") else {
            continue;
        };
        // `Trace 0: 0x7f2af0000100 [00800408/00000400/00000110/ff020200] Reset`
        let Some((host, pc)) = parse_exec(rest) else {
            continue;
        };
        if let Some(b) = block
            .take()
            .filter(|b| b.first().is_some_and(|i| i.addr == pc))
        {
            let func = symbols.index(pc);
            by_host.insert(host, tbs.len());
            tbs.push(Tb { insns: b, func });
        }
        let Some(&tb) = by_host.get(&host) else {
            continue;
        };
        let first = &tbs[tb].insns[0];
        let next = Some((first.addr, first.size));
        if let Some((p, r)) = prev.take() {
            let c = machine.run(&tbs[p].insns, next);
            match r {
                Some(Region::Tick) => {
                    per_fn[tbs[p].func] += c.cycles();
                    if let Some(t) = out.ticks.last_mut() {
                        t.add(&c);
                    }
                }
                Some(Region::Fill) => {
                    if let Some(f) = out.fills.last_mut() {
                        f.add(&c);
                    }
                }
                None => {}
            }
        }
        let marker = if pc == markers.tick_begin {
            region = Some(Region::Tick);
            out.ticks.push(Cost::default());
            per_fn.iter_mut().for_each(|c| *c = 0);
            true
        } else if pc == markers.fill_begin {
            region = Some(Region::Fill);
            out.fills.push(Cost::default());
            true
        } else if pc == markers.tick_end {
            if region == Some(Region::Tick) {
                let cycles = out.ticks.last().map_or(0, Cost::cycles);
                if cycles > worst_cycles {
                    worst_cycles = cycles;
                    worst_fn.clone_from(&per_fn);
                }
            }
            region = None;
            true
        } else if pc == markers.fill_end {
            region = None;
            true
        } else {
            false
        };
        prev = Some((tb, if marker { None } else { region }));
    }
    let mut top: Vec<(String, u64)> = worst_fn
        .iter()
        .enumerate()
        .filter(|(_, &c)| c > 0)
        .map(|(i, &c)| (symbols.name(i).to_string(), c))
        .collect();
    top.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    out.worst_tick_functions = top;
    Ok(out)
}

/// The host pointer and guest PC of an exec line (after `Trace `).
fn parse_exec(rest: &str) -> Option<(u64, u32)> {
    let (_, rest) = rest.split_once(": ")?;
    let (host, rest) = rest.split_once(' ')?;
    let host = u64::from_str_radix(host.trim_start_matches("0x"), 16).ok()?;
    let inside = rest.strip_prefix('[')?.split_once(']')?.0;
    let pc = inside.split('/').nth(1)?;
    Some((host, u32::from_str_radix(pc, 16).ok()?))
}

/// The firmware module that holds the trace markers.
const MARKERS: &str = "maobi_firmware::app::bench";

/// The image's function symbols and the trace markers.
pub fn read_image(elf: &Path) -> Result<(Symbols, Markers)> {
    use object::{Object, ObjectSymbol, SymbolKind};
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*bytes)
        .with_context(|| format!("{} is not an ELF image", elf.display()))?;
    let mut funcs = Vec::new();
    let mut named: HashMap<String, u32> = HashMap::new();
    for s in file.symbols() {
        if s.kind() != SymbolKind::Text {
            continue;
        }
        let Ok(name) = s.name() else { continue };
        // Thumb code: bit 0 of a function's address is the state bit, not the address.
        let start = (s.address() & !1) as u32;
        // Without the hash: `maobi_firmware::app::bench::trace_tick_begin`.
        let name = format!("{:#}", rustc_demangle::demangle(name));
        if s.size() > 0 {
            funcs.push((start, start + s.size() as u32, name.clone()));
        }
        named.insert(name, start);
    }
    let find = |n: &str| {
        named.get(n).copied().with_context(|| {
            format!(
                "{} has no `{n}`: an image from before `bench SHIFT cycles` (rebuild the firmware)",
                elf.display()
            )
        })
    };
    let markers = Markers {
        tick_begin: find(&format!("{MARKERS}::trace_tick_begin"))?,
        tick_end: find(&format!("{MARKERS}::trace_tick_end"))?,
        fill_begin: find(&format!("{MARKERS}::trace_fill_begin"))?,
        fill_end: find(&format!("{MARKERS}::trace_fill_end"))?,
    };
    Ok((Symbols::new(funcs), markers))
}

/// The estimate `hil bench` prints.
#[derive(Clone, Debug)]
pub struct Estimate {
    /// Ticks traced.
    pub ticks: usize,
    /// The dearest traced tick (1-based, the bench stroke's tick) and its cost.
    pub worst_at: usize,
    pub worst: Cost,
    /// The dearest state fill.
    pub fill: Cost,
    /// The blocking ADC reads ([`adc_cycles`]).
    pub adc: u64,
    /// The worst tick's cycles by function, dearest first.
    pub top: Vec<(String, u64)>,
    /// The firmware's own `-icount` count of the traced ticks' dearest (instructions, to
    /// 40 / 2^shift), a check on the log's count.
    pub icount_max: Option<u64>,
}

impl Estimate {
    pub fn total(&self) -> u64 {
        self.worst.cycles() + self.fill.cycles() + self.adc
    }
    pub fn fits(&self) -> bool {
        self.total() <= GOAL_CYCLES
    }
}

/// Boots the image in `bench 3 cycles` under QEMU with its execution log on a pipe, and
/// weighs the bracketed ticks and state fills.
pub fn trace(elf: &Path, timeout: Duration) -> Result<Estimate> {
    let shift = 3;
    let (symbols, markers) = read_image(elf)?;
    let mut fds = [0; 2];
    // SAFETY: pipe2 writes two descriptors into the array it is given.
    if unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) } != 0 {
        return Err(std::io::Error::last_os_error()).context("creating the log pipe");
    }
    // SAFETY: both descriptors are new and owned here alone.
    let (read_end, write_end) =
        unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
    let mut run = Run::new(
        elf,
        &["bench", "3", "cycles"],
        Clock::Deterministic { shift },
        timeout,
    );
    let w = write_end.as_raw_fd();
    run.qemu_args = vec![
        "-d".into(),
        "in_asm,exec,nochain".into(),
        "-D".into(),
        format!("/dev/fd/{w}"),
    ];
    let mut cmd = run.command();
    cmd.stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null());
    // SAFETY: only fcntl(2) on a descriptor `write_end` keeps open until after the spawn.
    unsafe {
        cmd.pre_exec(move || crate::qemu::inherit_fd(w));
    }
    let mut child = cmd.spawn().with_context(|| {
        format!(
            "cannot start {} (install it: apt-get install qemu-system-arm)",
            crate::qemu::qemu_binary().display()
        )
    })?;
    // QEMU holds the only write end now: the log ends when QEMU does.
    drop(write_end);
    let reader = std::thread::spawn(move || {
        let log = BufReader::with_capacity(1 << 20, std::fs::File::from(read_end));
        weigh_log(log, markers, &symbols)
    });
    let deadline = Instant::now() + timeout;
    let status = loop {
        if let Some(s) = child.try_wait()? {
            break s;
        }
        if Instant::now() >= deadline {
            let _ = child.kill();
            let _ = child.wait();
            bail!("the traced bench did not finish within {timeout:?}: QEMU killed");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let mut out = String::new();
    if let Some(mut s) = child.stdout.take() {
        s.read_to_string(&mut out)?;
    }
    let traced = reader
        .join()
        .map_err(|_| anyhow::anyhow!("the log reader panicked"))??;
    if !status.success() {
        bail!("the traced bench failed ({status}):\n{out}");
    }
    let icount_max = out
        .lines()
        .find_map(|l| l.strip_prefix("BENCH tick "))
        .and_then(|l| {
            l.split_whitespace()
                .find_map(|w| w.strip_prefix("max_counts="))
        })
        .and_then(|v| v.parse::<u64>().ok())
        .map(|c| (c * 40) >> shift);
    let Some((i, worst)) = traced.worst_tick() else {
        bail!("QEMU's log held no bracketed tick (no `{MARKERS}::trace_tick_begin` ran):\n{out}");
    };
    if worst.instructions == 0 {
        bail!("QEMU's log held no disassembly of the tick (a QEMU built without a disassembler?)");
    }
    let fill = traced
        .worst_fill()
        .context("QEMU's log held no bracketed state fill")?;
    Ok(Estimate {
        ticks: traced.ticks.len(),
        worst_at: i + 1,
        worst,
        fill,
        adc: adc_cycles(),
        top: traced.worst_tick_functions,
        icount_max,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn insns(lines: &[&str]) -> Vec<Insn> {
        lines
            .iter()
            .map(|l| decode(l).unwrap_or_else(|| panic!("{l}")))
            .collect()
    }

    #[test]
    fn decodes_qemus_disassembly() {
        let i = decode("0x00000404:  4812       ldr      r0, [pc, #0x48]").unwrap();
        assert_eq!((i.addr, i.size, i.kind), (0x404, 2, Kind::Load));
        // Align(0x404 + 4, 4) + 0x48.
        assert_eq!(i.literal, Some((0x450, 4)));
        let i = decode("0x0001e914:  e9c2 3300  strd     r3, r3, [r2]").unwrap();
        assert_eq!((i.size, i.kind, i.branch), (4, Kind::Fixed(3), None));
        let i = decode("0x00000d4c:  bdf0       pop      {r4, r5, r6, r7, pc}").unwrap();
        assert_eq!(i.kind, Kind::Fixed(6));
        assert_eq!(i.branch, Some(Branch::Memory));
        let i = decode("0x00000e10:  d9f8       bls      #0xe04").unwrap();
        assert_eq!((i.kind, i.branch), (Kind::Fixed(1), Some(Branch::Direct)));
        let i = decode("0x00000906:  4718       bx       r3").unwrap();
        assert_eq!(i.branch, Some(Branch::Register));
        let i = decode("0x00000000:  5888       ldr      r0, [r1, r2]").unwrap();
        assert_eq!((i.writes, i.addr_regs), (0b1, 0b110));
        let i = decode("0x00000000:  f85d 8b04  ldr      r8, [sp], #4").unwrap();
        assert_eq!((i.writes, i.addr_regs), (1 << 8, 1 << 13));
        let i = decode("0x00000000:  fba2 0103  umull    r0, r1, r2, r3").unwrap();
        assert_eq!((i.writes, i.addr_regs), (0b11, 0));
        let i = decode("0x00000000:  4288       cmp      r0, r1").unwrap();
        assert_eq!(i.writes, 0);
        let i = decode("0x00000000:  e8d0 f001  tbb      [r0, r1]").unwrap();
        assert_eq!(
            (i.kind, i.branch, i.addr_regs),
            (Kind::Fixed(3), Some(Branch::Memory), 0b11)
        );
        let i = decode("0x00000e1c:  4372       muls     r2, r6, r2").unwrap();
        assert_eq!((i.kind, i.branch), (Kind::Fixed(1), None));
        let i = decode("0x00000ac8:  e89c 1030  ldm.w    ip, {r4, r5, ip}").unwrap();
        assert_eq!(i.kind, Kind::Fixed(4));
        let i = decode("0x00000e30:  52f1       strh     r1, [r6, r3]").unwrap();
        assert_eq!(i.kind, Kind::Store { imm: false });
        let i = decode("0x00000bf2:  f04f 0c00  movlo.w  ip, #0").unwrap();
        assert_eq!(i.kind, Kind::Fixed(1));
        let i = decode("0x00001000:  ed90 0b00  vldr     d0, [r0]").unwrap();
        assert_eq!(i.kind, Kind::Fixed(3));
        let i = decode("0x00001000:  ec51 0b10  vmov     r0, r1, d0").unwrap();
        assert_eq!(i.kind, Kind::Fixed(2));
        let i = decode("0x00001000:  ee10 0a10  vmov     r0, s0").unwrap();
        assert_eq!(i.kind, Kind::Fixed(1));
        let i = decode("0x00001000:  eec0 0a20  vdiv.f32 s1, s0, s1").unwrap();
        assert_eq!(i.kind, Kind::Fixed(14));
        let i = decode("0x00001000:  ed2d 8b04  vpush    {d8, d9}").unwrap();
        assert_eq!(i.kind, Kind::Fixed(5));
        let i = decode("0x00001000:  fb90 f0f1  sdiv     r0, r0, r1").unwrap();
        assert_eq!(i.kind, Kind::Fixed(DIVIDE_CYCLES));
        let i = decode("0x0001331c:  b110       cbz      r0, #0x13324").unwrap();
        assert_eq!(i.branch, Some(Branch::Direct));
        let i = decode("0x00000000:  bf1c       itt      ne").unwrap();
        assert_eq!(i.kind, Kind::Fixed(1));
        assert_eq!(decode("IN: Reset"), None);
    }

    /// Loads pipeline after a load, not after a store; an immediate-offset store is 1.
    #[test]
    fn loads_and_stores() {
        let code = insns(&[
            "0x00000000:  6808       ldr      r0, [r1]",
            "0x00000002:  684a       ldr      r2, [r1, #4]",
            "0x00000004:  6008       str      r0, [r1]",
            "0x00000006:  688b       ldr      r3, [r1, #8]",
            "0x00000008:  1880       adds     r0, r0, r2",
            "0x0000000a:  50ca       str      r2, [r1, r3]",
        ]);
        let c = Machine::new().run(&code, None);
        // 2 + 1 (pipelined) + 1 (imm store) + 2 (after a store) + 1 + 2 (reg offset, after
        // an add); one line, fetched once from flash.
        assert_eq!(c.core, 9);
        assert_eq!((c.icache_misses, c.flash_stalls), (1, 3));
        assert_eq!(c.instructions, 6);
    }

    /// A load's or store's address from the result of the instruction before it: one stall
    /// after a data-processing result; no pipelining after the load that loaded it.
    #[test]
    fn address_dependencies() {
        let run = |lines: &[&str]| Machine::new().run(&insns(lines), None).core;
        // 1 + (2 + 1).
        assert_eq!(
            run(&[
                "0x00000000:  3104       adds     r1, #4",
                "0x00000002:  6808       ldr      r0, [r1]",
            ]),
            4
        );
        // The add writes r2, the load's address is r1: 1 + 2.
        assert_eq!(
            run(&[
                "0x00000000:  3204       adds     r2, #4",
                "0x00000002:  6808       ldr      r0, [r1]",
            ]),
            3
        );
        // A pointer chase: 2 + 2; two independent loads: 2 + 1.
        assert_eq!(
            run(&[
                "0x00000000:  6801       ldr      r1, [r0]",
                "0x00000002:  680a       ldr      r2, [r1]",
            ]),
            4
        );
        assert_eq!(
            run(&[
                "0x00000000:  6801       ldr      r1, [r0]",
                "0x00000002:  6842       ldr      r2, [r0, #4]",
            ]),
            3
        );
    }

    /// A taken branch costs 1 + P; not taken, 1. P is 1 for a direct branch, 2 from a
    /// register, 3 from memory, 1 more (up to 3) for an unaligned 32-bit target.
    #[test]
    fn branches() {
        let b = decode("0x00000000:  d1fe       bne      #0x0").unwrap();
        let mut m = Machine::new();
        // Taken to an aligned 16-bit instruction: 1 + 1.
        assert_eq!(m.step(&b, Some((0x0, 2))).core, 2);
        // Not taken.
        assert_eq!(m.step(&b, Some((0x2, 2))).core, 1);
        // Taken to a 32-bit instruction at 2 mod 4: 1 + 2.
        assert_eq!(m.step(&b, Some((0x6, 4))).core, 3);
        let bx = decode("0x00000000:  4770       bx       lr").unwrap();
        // 1 + 2; to an unaligned 32-bit target 1 + 3.
        assert_eq!(m.step(&bx, Some((0x100, 2))).core, 3);
        assert_eq!(m.step(&bx, Some((0x102, 4))).core, 4);
        let pop = decode("0x00000000:  bd80       pop      {r7, pc}").unwrap();
        // 1 + N (2) + P (3: the target comes from memory).
        let c = m.step(&pop, Some((0x100, 2)));
        assert_eq!((c.core, c.taken_branches, c.refill), (6, 1, 3));
        // With P at 1 the pop costs 4, at 3 it costs 6 (plus its line's flash miss).
        assert_eq!(c.refill_range(), (4 + c.flash_stalls, 6 + c.flash_stalls));
        let push = decode("0x00000000:  b580       push     {r7, lr}").unwrap();
        assert_eq!(m.step(&push, Some((0x2, 2))).core, 3);
    }

    /// A loop in one line fetches it once; jumping among 65 lines in turn misses every
    /// time (LRU of 64), among 64 only the first round.
    #[test]
    fn instruction_cache() {
        let jump = |line: u32| Insn {
            branch: Some(Branch::Direct),
            ..Insn::plain(line * LINE_BYTES, 2, Kind::Fixed(1))
        };
        for (lines, misses) in [(64u32, 64u64), (65, 65 * 3)] {
            let mut m = Machine::new();
            let mut total = Cost::default();
            // Every other line, so that no jump lands in the prefetched next line.
            for round in 0..3 {
                for l in 0..lines {
                    let target = ((l + 1) % lines) * 2;
                    total.add(&m.step(&jump(l * 2), Some((target * LINE_BYTES, 2))));
                    let _ = round;
                }
            }
            assert_eq!(total.icache_misses, misses, "{lines} lines");
            assert_eq!(total.flash_stalls, misses * 3);
        }
        // Straight-line code over three lines: one miss, the rest prefetched.
        let code: Vec<Insn> = (0..24)
            .map(|i| Insn::plain(0x100 + i * 2, 2, Kind::Fixed(1)))
            .collect();
        let c = Machine::new().run(&code, None);
        assert_eq!((c.core, c.icache_misses), (24, 1));
    }

    /// Literals through the 8-line data cache: nine lines in turn miss every time.
    #[test]
    fn literal_pool_cache() {
        for (lines, misses) in [(8u32, 8u64), (9, 27)] {
            let mut m = Machine::new();
            let mut d = 0;
            for _ in 0..3 {
                for l in 0..lines {
                    let ld = Insn {
                        literal: Some((0x1000 + l * LINE_BYTES, 4)),
                        ..Insn::plain(0, 2, Kind::Load)
                    };
                    d += m.step(&ld, None).dcache_misses;
                }
            }
            assert_eq!(d, misses, "{lines} lines");
        }
    }

    /// Per channel (84 + 12) ADC cycles of 4 core cycles each; no power-up wait (the ADC is
    /// switched on once, at boot).
    #[test]
    fn adc_reads() {
        assert_eq!(adc_cycles(), 3 * 96 * 4);
    }

    /// The ADC's and the clock's constants here are the Black Pill's configuration's: a
    /// change there must change them too.
    #[test]
    fn adc_constants_match_the_black_pills_configuration() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/src/blackpill");
        let read = |f: &str| std::fs::read_to_string(dir.join(f)).unwrap();
        let sensors = read("sensors.rs");
        let board = read("mod.rs");
        assert!(sensors.contains(&format!(
            "SampleTime = SampleTime::CYCLES{ADC_SAMPLE_CYCLES};"
        )));
        assert!(sensors.contains(&format!("InjectedAdc<'static, ADC1, {ADC_CHANNELS}>")));
        // One scan per read, and no embassy `blocking_read` (its power-up wait per read is
        // what the scan removed).
        assert_eq!(sensors.matches("start_injected_conversions()").count(), 1);
        assert!(!sensors.contains(".blocking_read("));
        assert!(board.contains(&format!(
            "pub const SYSCLK_HZ: u32 = {}_000_000;",
            SYSCLK_HZ / 1_000_000
        )));
        // PCLK2 = SYSCLK, which embassy divides by 4 for the ADC's 36 MHz limit.
        assert!(board.contains("config.rcc.apb2_pre = APBPrescaler::DIV1;"));
        // embassy-stm32 0.6 `adc/v2.rs` `from_pclk2`: the even divider 2, 4, 6 or 8 for
        // `(pclk2 - 1) / 36 MHz` of 0-1, 2-3, 4-5 or 6-7.
        assert_eq!(ADC_PRESCALER, 2 * ((SYSCLK_HZ - 1) / 36_000_000 / 2 + 1));
    }

    /// The log's blocks, their executions and the markers: only the bracketed blocks count.
    #[test]
    fn weighs_the_bracketed_blocks() {
        let log = "\
IN: f
0x00000100:  2001       movs     r0, #1
0x00000102:  e7fd       b        #0x100

Trace 0: 0x10 [0/00000100/0/0] f
IN: begin
0x00000200:  4770       bx       lr

Trace 0: 0x20 [0/00000200/0/0] begin
Trace 0: 0x10 [0/00000100/0/0] f
Trace 0: 0x10 [0/00000100/0/0] f
IN: end
0x00000300:  4770       bx       lr

Trace 0: 0x30 [0/00000300/0/0] end
Trace 0: 0x10 [0/00000100/0/0] f
";
        let markers = Markers {
            tick_begin: 0x200,
            tick_end: 0x300,
            fill_begin: 0x400,
            fill_end: 0x500,
        };
        let symbols = Symbols::new(vec![(0x100, 0x104, "f".into())]);
        let t = weigh_log(log.as_bytes(), markers, &symbols).unwrap();
        assert_eq!(t.ticks.len(), 1);
        let c = t.ticks[0];
        // Two runs of `movs` (1) + `b` taken (1 + 1), the second to `end`'s block. The line
        // at 0x100 missed before the tick (uncharged) and is an I-cache hit on the return
        // from `begin`'s line: no stall inside the tick.
        assert_eq!((c.instructions, c.core, c.taken_branches), (4, 6, 2));
        assert_eq!((c.icache_misses, c.flash_stalls), (0, 0), "{c:?}");
        assert_eq!(t.worst_tick_functions, vec![("f".to_string(), c.cycles())]);
        assert!(t.fills.is_empty());
    }
}
