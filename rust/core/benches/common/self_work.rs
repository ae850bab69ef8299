//! What the self-collision benchmark and the `self_replay` example print of a
//! step (issue 30), shared so that their lines read alike: the CPU time, and
//! where the self-collision work went.

use tegument_core::sequence::SelfWork;

/// CPU seconds this process has used, all threads (`/proc/self/stat`'s utime + stime, in
/// clock ticks of 1/100 s, Linux's `USER_HZ`): on a shared host, what a step cost without the
/// other jobs' load. None off Linux.
pub fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The fields after the command name, which is in parentheses and may hold spaces.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |k: usize| fields.get(k)?.parse::<f64>().ok();
    // utime and stime are the 14th and 15th fields; `rest` starts at the 3rd.
    Some((ticks(11)? + ticks(12)?) / 100.0)
}

/// A step's self-collision phases and gatherings, as one line's tail.
pub fn work_line(w: &SelfWork) -> String {
    format!(
        "phases ms: begin {:.1}, first pass {:.1}, in-loop rounds {:.1}, in-loop fail-safe {:.1}, tangles {:.1}; gathers {} whole ({} in-loop) + {} around, most candidates {}; \
         within, ms: first gathers {:.1}, in-loop gathers {:.1}, around {:.1}, round tests {:.1}, fail-safe checks {:.1}; pairs scanned {}, tested {}",
        w.begin_ms,
        w.first_pass_ms,
        w.in_loop_rounds_ms,
        w.in_loop_fail_safe_ms,
        w.tangles_ms,
        w.gathers,
        w.in_loop_gathers,
        w.gathers_around,
        w.most_candidates,
        w.first_gather_ms,
        w.in_loop_gather_ms,
        w.around_gather_ms,
        w.rounds_ms,
        w.fail_safe_checks_ms,
        w.pairs_scanned,
        w.pairs_tested
    )
}
