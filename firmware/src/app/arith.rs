//! The fixed-point operators checked on the device: `maobi-fw arith` under QEMU.
//!
//! On the Cortex-M4F, `Fx`'s add, subtract and coefficient multiply are inline assembly
//! (`maobi_shared::scalar::raw`), which no host test can execute, and its multiply takes
//! the 32-bit targets' partial-product path. This runs each against its portable 128-bit
//! reference, compiled for this core too: every pair of a table of edge values
//! (zero, one, the format's ends and the word boundaries where carries and borrows cross),
//! then pseudo-random operands of every magnitude. Prints one `ARITH` line per operator and
//! `ARITH mismatches=N`; the `hil` test `arith` asserts there are none.

use core::fmt::Write;
use core::hint::black_box;

use maobi_shared::scalar::raw;

/// Pseudo-random cases per operator after the edge table.
pub const RANDOM_CASES: u32 = 1_000_000;

/// Values at which a 64-bit add, subtract or multiply changes behaviour: signs, the ends of
/// the range, the 32-bit word boundary (carries from the low word, the `2^32` = 1.0 of
/// the format), and the ends of the multiply's short path (high words in `[-2^15, 2^15)`).
const EDGES: [i64; 26] = [
    0,
    1,
    -1,
    2,
    i64::MAX,
    i64::MIN,
    i64::MAX - 1,
    i64::MIN + 1,
    1 << 32,
    -(1 << 32),
    (1 << 32) - 1,
    -(1 << 32) + 1,
    1 << 31,
    -(1 << 31),
    (1 << 31) - 1,
    0x0000_0001_8000_0000,
    -0x0000_0001_8000_0000,
    1 << 62,
    -(1 << 62),
    0x7fff_ffff_0000_0000,
    0x1234_5678_9abc_def0,
    -0x1234_5678_9abc_def0,
    0x0000_7fff_ffff_ffff,
    0x0000_8000_0000_0000,
    -0x0000_8000_0000_0000,
    -0x0000_8000_0000_0001,
];

/// One operator's tally.
#[derive(Default)]
struct Tally {
    cases: u32,
    mismatches: u32,
    /// The first mismatch: operands, what the operator gave, what the reference gives.
    first: Option<(i64, i64, i64, i64)>,
}

impl Tally {
    fn check(&mut self, a: i64, b: i64, got: i64, want: i64) {
        self.cases += 1;
        if got != want {
            self.mismatches += 1;
            self.first.get_or_insert((a, b, got, want));
        }
    }
}

/// xorshift64: a fixed sequence, so a failure reproduces.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    /// A value of random magnitude: shifted right by 0..=63 bits, so small numbers (the
    /// model's millimetres and coefficients) are as common as large ones.
    fn operand(&mut self) -> i64 {
        let r = self.next();
        (r as i64) >> (self.next() % 64)
    }
    /// A raw coefficient, `-2^32 < c < 2^32` (magnitude below 1.0).
    fn coefficient(&mut self) -> i64 {
        let c = (self.next() as i64) >> (31 + self.next() % 33);
        c.max(-(1 << 32) + 1)
    }
}

/// Runs the checks, writes the report to `out`, and returns the total of mismatches.
pub fn run(out: &mut impl Write) -> u32 {
    let (mut add, mut sub) = (Tally::default(), Tally::default());
    let (mut mul, mut mul_coef) = (Tally::default(), Tally::default());
    let coef = |v: i64| -(1 << 32) < v && v < 1 << 32;
    let mut case = |a: i64, b: i64| {
        let (a, b) = (black_box(a), black_box(b));
        add.check(a, b, raw::add(a, b), raw::add_reference(a, b));
        sub.check(a, b, raw::sub(a, b), raw::sub_reference(a, b));
        mul.check(a, b, raw::mul(a, b), raw::mul_reference(a, b));
        if coef(b) {
            mul_coef.check(a, b, raw::mul_coef(a, b), raw::mul_coef_reference(a, b));
        }
    };
    for &a in &EDGES {
        for &b in &EDGES {
            case(a, b);
        }
    }
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    for _ in 0..RANDOM_CASES {
        let (a, b) = (rng.operand(), rng.operand());
        case(a, b);
        let c = rng.coefficient();
        case(a, c);
    }
    let mut total = 0;
    for (name, t) in [
        ("add", &add),
        ("sub", &sub),
        ("mul", &mul),
        ("mul_coef", &mul_coef),
    ] {
        let _ = write!(
            out,
            "ARITH op={name} cases={} mismatches={}",
            t.cases, t.mismatches
        );
        if let Some((a, b, got, want)) = t.first {
            let _ = write!(
                out,
                " first: a={a:#018x} b={b:#018x} got={got:#018x} want={want:#018x}"
            );
        }
        let _ = writeln!(out);
        total += t.mismatches;
    }
    let _ = writeln!(out, "ARITH mismatches={total}");
    total
}
