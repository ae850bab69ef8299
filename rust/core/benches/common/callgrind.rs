//! Callgrind's client requests, so that a benchmark run under
//! `valgrind --tool=callgrind` can count the instructions of one step (all
//! threads) rather than of the whole process: zero the counters before the
//! step, dump them after it with a label. Outside valgrind each request is
//! a no-op (rotations of a register by 128 bits in all and an exchange of a
//! register with itself), so the benchmarks' timings are unaffected.
//!
//! On a shared host the clocks swing with the load; instruction counts are
//! repeatable whatever it is. `callgrind.out.<pid>.<k>` then holds dump `k`,
//! its `desc: Trigger: Client Request: <label>` line the label and its
//! `summary:` line the instructions.

use std::ffi::CStr;

/// Callgrind's requests (`valgrind/callgrind.h`): the tool base `'C','T'`,
/// then in order dump, zero, toggle collection, dump with a label, start
/// and stop instrumentation.
const TOOL_BASE: u64 = ((b'C' as u64) << 24) | ((b'T' as u64) << 16);
const ZERO_STATS: u64 = TOOL_BASE + 1;
const DUMP_STATS_AT: u64 = TOOL_BASE + 3;
const START_INSTRUMENTATION: u64 = TOOL_BASE + 4;
const STOP_INSTRUMENTATION: u64 = TOOL_BASE + 5;

/// Valgrind's client request on x86-64 (`valgrind/valgrind.h`,
/// `VALGRIND_DO_CLIENT_REQUEST_EXPR`): the arguments' address in `rax`, the
/// answer in `rdx` (the default where valgrind is not running).
#[cfg(target_arch = "x86_64")]
fn request(code: u64, argument: u64) -> u64 {
    let arguments: [u64; 6] = [code, argument, 0, 0, 0, 0];
    let mut answer: u64 = 0;
    // SAFETY: the sequence leaves every register as it found it (`rdi` is
    // rotated by 3 + 13 + 61 + 51 = 128 bits, `rbx` exchanged with itself)
    // except `rdx`, declared, and the flags, which `asm!` assumes clobbered;
    // valgrind reads the six words `rax` points at, which live until after it.
    unsafe {
        std::arch::asm!(
            "rol rdi, 3",
            "rol rdi, 13",
            "rol rdi, 61",
            "rol rdi, 51",
            "xchg rbx, rbx",
            in("rax") arguments.as_ptr(),
            inout("rdx") answer,
        );
    }
    answer
}

#[cfg(not(target_arch = "x86_64"))]
fn request(_code: u64, _argument: u64) -> u64 {
    0
}

/// Callgrind's counters of every thread back to zero.
pub fn zero_stats() {
    request(ZERO_STATS, 0);
}

/// Callgrind writes its counters since the last dump or zeroing, every
/// thread's, to the next `callgrind.out` file, labelled `label`, and zeroes them.
pub fn dump_stats_at(label: &CStr) {
    request(DUMP_STATS_AT, label.as_ptr() as u64);
}

/// Callgrind counts from here on (a run started with `--instr-atstart=no`
/// runs uninstrumented, several times faster, until this).
#[allow(dead_code)]
pub fn start_instrumentation() {
    request(START_INSTRUMENTATION, 0);
}

/// Callgrind stops counting until [`start_instrumentation`].
#[allow(dead_code)]
pub fn stop_instrumentation() {
    request(STOP_INSTRUMENTATION, 0);
}
