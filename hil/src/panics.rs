//! Bounds-check panics the force path can reach, read from the firmware image.
//!
//! The force loop must hold no panicking index (a panic there stops the pen: its motors go
//! off, safely, but the stroke is lost). Bounds checks are inserted by the compiler wherever
//! it cannot prove an index in range, and a source change far from the index can bring them
//! back, so the check is on the machine code: from the board's interrupt handler that runs
//! the force loop's tick, every function
//! it calls or tail-calls (Thumb-2 `BL` and `B.W`, conditional or not) is walked, and any
//! call to Rust's index-panic entry points is reported with the function it sits in.
//!
//! Not followed: calls through registers (the force path makes none: its generic code is
//! monomorphised) and the panic machinery itself (`core::panicking`, the handler), which is
//! where such calls lead, not where they come from.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::Path;

use anyhow::{bail, Context, Result};
use object::{Object, ObjectSection, ObjectSymbol, SymbolKind};

/// Rust's entry points for an index or a range out of bounds (core's names, old and new).
const INDEX_PANICS: [&str; 5] = [
    "panic_bounds_check",
    "slice_index_fail",
    "slice_start_index_len_fail",
    "slice_end_index_len_fail",
    "slice_index_order_fail",
];

/// One call to an index panic reachable from the force loop.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PanicCall {
    /// The function holding the call (demangled, without its hash).
    pub function: String,
    /// The call instruction's address.
    pub address: u64,
    /// Which panic it calls.
    pub panic: String,
}

/// A function symbol: start (Thumb bit cleared), size, demangled name.
struct Function {
    size: u64,
    name: String,
}

/// The index panics reachable from the function named `root` (demangled, without its hash:
/// the board's force-loop interrupt handler), and how many functions the walk visited.
/// Fails if no function has that name.
pub fn reachable_index_panics(elf: &Path, root: &str) -> Result<(Vec<PanicCall>, usize)> {
    let data = std::fs::read(elf).with_context(|| format!("cannot read {}", elf.display()))?;
    let file = object::File::parse(&*data)
        .with_context(|| format!("{} is not an object file", elf.display()))?;
    let mut functions = BTreeMap::new();
    // Several names may share an address (cortex-m-rt's exception aliases): roots by name.
    let mut queue = VecDeque::new();
    for s in file.symbols() {
        if s.kind() != SymbolKind::Text || s.size() == 0 {
            continue;
        }
        let Ok(raw) = s.name() else { continue };
        let name = format!("{:#}", rustc_demangle::demangle(raw));
        if name == root {
            queue.push_back(s.address() & !1);
        }
        functions.insert(
            s.address() & !1,
            Function {
                size: s.size(),
                name,
            },
        );
    }
    let code = |addr: u64, size: u64| -> Option<&[u8]> {
        file.sections().find_map(|sec| {
            let start = sec.address();
            if addr < start || addr + size > start + sec.size() {
                return None;
            }
            let bytes = sec.data().ok()?;
            let from = usize::try_from(addr - start).ok()?;
            bytes.get(from..from + usize::try_from(size).ok()?)
        })
    };
    let is_panic_machinery = |name: &str| {
        name.contains("core::panicking")
            || name.contains("rust_begin_unwind")
            || name.contains("::panic")
            || name.starts_with("panic")
    };

    if queue.is_empty() {
        bail!(
            "{}: no function named {root} (is it the firmware image?)",
            elf.display()
        );
    }
    let mut seen: BTreeSet<u64> = queue.iter().copied().collect();
    let mut found = Vec::new();
    while let Some(start) = queue.pop_front() {
        let Some(f) = functions.get(&start) else {
            continue;
        };
        let Some(bytes) = code(start, f.size) else {
            continue;
        };
        for (at, target) in branch_targets(start, bytes) {
            let Some(callee) = functions.get(&target) else {
                continue;
            };
            if let Some(p) = INDEX_PANICS.iter().find(|p| callee.name.contains(*p)) {
                found.push(PanicCall {
                    function: f.name.clone(),
                    address: at,
                    panic: (*p).to_string(),
                });
            } else if !is_panic_machinery(&callee.name) && seen.insert(target) {
                queue.push_back(target);
            }
        }
    }
    Ok((found, seen.len()))
}

/// Every `BL` and 32-bit `B` (T3 conditional, T4 unconditional) in Thumb-2 `code` placed at
/// `base`: (instruction address, target address).
fn branch_targets(base: u64, code: &[u8]) -> Vec<(u64, u64)> {
    let half = |i: usize| -> Option<u32> {
        Some(u16::from_le_bytes([*code.get(i)?, *code.get(i + 1)?]) as u32)
    };
    let mut out = Vec::new();
    let mut i = 0;
    while let Some(h1) = half(i) {
        // A 32-bit instruction starts with 0b11101, 0b11110 or 0b11111.
        if h1 >> 11 < 0b11101 {
            i += 2;
            continue;
        }
        let Some(h2) = half(i + 2) else { break };
        let pc = base + i as u64 + 4;
        if h1 >> 11 == 0b11110 {
            let s = (h1 >> 10) & 1;
            let (j1, j2) = ((h2 >> 13) & 1, (h2 >> 11) & 1);
            let offset = match h2 & 0xD000 {
                // BL (T1) and B.W (T4): S:I1:I2:imm10:imm11:0, I = !(J ^ S).
                0xD000 | 0x9000 => {
                    let (i1, i2) = (!(j1 ^ s) & 1, !(j2 ^ s) & 1);
                    let v = (s << 24)
                        | (i1 << 23)
                        | (i2 << 22)
                        | ((h1 & 0x3FF) << 12)
                        | ((h2 & 0x7FF) << 1);
                    Some(sign_extend(v, 25))
                }
                // B<cond>.W (T3): S:J2:J1:imm6:imm11:0 (cond 0b111x is another encoding).
                0x8000 if (h1 >> 7) & 0b111 != 0b111 => {
                    let v = (s << 20)
                        | (j2 << 19)
                        | (j1 << 18)
                        | ((h1 & 0x3F) << 12)
                        | ((h2 & 0x7FF) << 1);
                    Some(sign_extend(v, 21))
                }
                _ => None,
            };
            if let Some(off) = offset {
                out.push((base + i as u64, pc.wrapping_add_signed(off)));
            }
        }
        i += 4;
    }
    out
}

/// `v`'s low `bits` bits as a signed number.
fn sign_extend(v: u32, bits: u32) -> i64 {
    let shift = 64 - bits;
    ((v as i64) << shift) >> shift
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Encodings from `llvm-objdump` of the Black Pill image (`bl` forward and backward) and
    /// hand-assembled ones (`b.w`, a conditional `bhi.w`).
    #[test]
    fn thumb2_branches_decode_to_their_targets() {
        let at = |h1: u16, h2: u16| {
            let mut b = h1.to_le_bytes().to_vec();
            b.extend_from_slice(&h2.to_le_bytes());
            b
        };
        // 8000198: 0d f0 50 fe  bl 0x800de3c
        assert_eq!(
            branch_targets(0x0800_0198, &at(0xF00D, 0xFE50)),
            vec![(0x0800_0198, 0x0800_de3c)]
        );
        // 800194c: ff f7 bc ff  bl 0x80018c8
        assert_eq!(
            branch_targets(0x0800_194c, &at(0xF7FF, 0xFFBC)),
            vec![(0x0800_194c, 0x0800_18c8)]
        );
        // bl +0x100 from 0x1000: target 0x1104.
        let bl_fwd = at(0xF000, 0xF880);
        assert_eq!(branch_targets(0x1000, &bl_fwd), vec![(0x1000, 0x1104)]);
        // b.w +0x100 from 0x1000 (T4).
        let bw = at(0xF000, 0xB880);
        assert_eq!(branch_targets(0x1000, &bw), vec![(0x1000, 0x1104)]);
        // bhi.w +0x40 from 0x2000 (T3, cond 8).
        let bhi = at(0xF200, 0x8020);
        assert_eq!(branch_targets(0x2000, &bhi), vec![(0x2000, 0x2044)]);
        // 16-bit instructions are skipped whole: a `movs` then the `bl`.
        let mut mixed = 0x2303u16.to_le_bytes().to_vec();
        mixed.extend(at(0xF000, 0xF880));
        assert_eq!(branch_targets(0x1000, &mixed), vec![(0x1002, 0x1106)]);
    }
}
