// Shared by the fuzz tests of several crates (`include!`d): a counting global allocator,
// mutations of valid seed files, the fuzz budget.

/// Counting global allocator: the peak of bytes allocated (net of frees) on the armed thread
/// while armed, so a reader's memory can be bounded by the size of its input.
mod counting {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    pub struct Counting;
    thread_local! {
        static ARMED: Cell<bool> = const { Cell::new(false) };
        static LIVE: Cell<isize> = const { Cell::new(0) };
        static PEAK: Cell<isize> = const { Cell::new(0) };
    }

    fn add(delta: isize) {
        let _ = ARMED.try_with(|a| {
            if a.get() {
                let _ = LIVE.try_with(|l| {
                    let v = l.get() + delta;
                    l.set(v);
                    let _ = PEAK.try_with(|p| p.set(p.get().max(v)));
                });
            }
        });
    }

    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            add(layout.size() as isize);
            unsafe { System.alloc(layout) }
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            add(-(layout.size() as isize));
            unsafe { System.dealloc(ptr, layout) }
        }
        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            add(new_size as isize - layout.size() as isize);
            unsafe { System.realloc(ptr, layout, new_size) }
        }
    }

    /// Runs `f` and returns its result and the peak of net bytes it allocated.
    pub fn measure<R>(f: impl FnOnce() -> R) -> (R, usize) {
        LIVE.with(|l| l.set(0));
        PEAK.with(|p| p.set(0));
        ARMED.with(|a| a.set(true));
        let r = f();
        ARMED.with(|a| a.set(false));
        (r, PEAK.with(|p| p.get()).max(0) as usize)
    }
}

#[global_allocator]
static GLOBAL: counting::Counting = counting::Counting;

/// Mutations applied to a valid seed file: the fuzz input.
#[derive(Debug, Clone)]
enum Mutation {
    /// Overwrite the byte at (position mod len).
    Byte(usize, u8),
    /// Insert a token at (position mod len): numbers at and beyond every bound, syntax.
    Insert(usize, &'static str),
    /// Delete up to n bytes at (position mod len).
    Delete(usize, usize),
    /// Cut the file at (position mod len).
    Truncate(usize),
    /// Repeat the line around (position mod len) n times.
    Repeat(usize, usize),
}

const TOKENS: &[&str] = &[
    "1e308", "-1e308", "1e30", "inf", "-inf", "nan", "NaN", "0", "-0", "-1", "1e-320",
    "18446744073709551615", "18446744073709551616", "9223372036854775807", "-9223372036854775808",
    "4294967295", "4294967296", "99999999999999999999999", "0x10", "\n", " ", ",", ".", "=",
    "[", "]", "\"", "#", "$", "$EndNodes", "$Nodes", "$Elements", "v", "f", "vt", "vn",
    "facet", "endsolid", "\u{0}", "é", "1.5", "3", "4",
];

fn mutation() -> impl proptest::strategy::Strategy<Value = Mutation> {
    use proptest::prelude::*;
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(p, b)| Mutation::Byte(p, b)),
        (any::<usize>(), proptest::sample::select(TOKENS)).prop_map(|(p, t)| Mutation::Insert(p, t)),
        (any::<usize>(), 1usize..64).prop_map(|(p, n)| Mutation::Delete(p, n)),
        any::<usize>().prop_map(Mutation::Truncate),
        (any::<usize>(), 1usize..200).prop_map(|(p, n)| Mutation::Repeat(p, n)),
    ]
}

/// Mutated files stay below this size (the seeds are a few kB).
const MAX_FUZZ_FILE: usize = 1 << 20;

fn mutate(seed: &[u8], mutations: &[Mutation]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for m in mutations {
        let len = b.len().max(1);
        match *m {
            Mutation::Byte(p, v) => {
                if !b.is_empty() {
                    b[p % len] = v;
                }
            }
            Mutation::Insert(p, t) => {
                let at = p % (b.len() + 1);
                b.splice(at..at, t.bytes());
            }
            Mutation::Delete(p, n) => {
                let at = p % len;
                let end = (at + n).min(b.len());
                if at < end {
                    b.drain(at..end);
                }
            }
            Mutation::Truncate(p) => b.truncate(p % len),
            Mutation::Repeat(p, n) => {
                if b.is_empty() {
                    continue;
                }
                let at = p % len;
                let start = b[..at].iter().rposition(|&c| c == b'\n').map_or(0, |i| i + 1);
                let end = b[at..].iter().position(|&c| c == b'\n').map_or(b.len(), |i| at + i + 1);
                // Lines only (a binary file's "line" is the file: repeating it compounds).
                if end - start > 256 || b.len() > MAX_FUZZ_FILE {
                    continue;
                }
                let block: Vec<u8> = b[start..end].repeat(n);
                b.splice(end..end, block);
            }
        }
    }
    b
}

/// Fuzz budget: cases per reader (ARTHROSIM_FUZZ_CASES overrides; CI keeps the default).
fn fuzz_cases(default: u32) -> u32 {
    std::env::var("ARTHROSIM_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Allocation allowed for parsing `len` bytes: proportional to the size plus a constant.
fn alloc_limit(len: usize, per_byte: usize) -> usize {
    per_byte * len + (8 << 20)
}
