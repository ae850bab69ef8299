//! Shared harness of the benchmarks: timing, the memory-bandwidth reference,
//! thread pools of a chosen size, and the JSON rows `bench/collect.py` turns
//! into the table in `docs/performance.md`.
//!
//! Each benchmark binary (`harness = false`) prints its rows as it goes and
//! writes them to `bench/results/<benchmark>.json` at the end.

#![allow(dead_code)] // each bench binary uses a different part of this module

pub mod callgrind;
pub mod self_work;

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

/// One measured figure.
#[derive(Debug, Clone)]
pub struct Row {
    pub case: String,
    pub metric: String,
    pub value: f64,
    pub unit: String,
    pub threads: usize,
    pub note: String,
}

/// Collects rows of one benchmark binary.
pub struct Report {
    benchmark: String,
    rows: Vec<Row>,
}

impl Report {
    pub fn new(benchmark: &str) -> Self {
        println!("== {benchmark} ==");
        Report { benchmark: benchmark.to_string(), rows: Vec::new() }
    }

    pub fn add(&mut self, case: &str, metric: &str, value: f64, unit: &str, threads: usize, note: &str) {
        println!("{case:<32} {metric:<28} {value:>12.3} {unit:<6} threads={threads} {note}");
        self.rows.push(Row {
            case: case.into(),
            metric: metric.into(),
            value,
            unit: unit.into(),
            threads,
            note: note.into(),
        });
    }

    /// Writes `bench/results/<benchmark>.json` (hand-written JSON: the rows
    /// are flat and the core crate has no serde).
    pub fn save(&self) {
        let dir = results_dir();
        std::fs::create_dir_all(&dir).expect("create bench/results");
        let mut text = String::from("[\n");
        for (i, row) in self.rows.iter().enumerate() {
            text += &format!(
                "  {{\"benchmark\": {}, \"case\": {}, \"metric\": {}, \"value\": {}, \"unit\": {}, \"threads\": {}, \"note\": {}}}{}\n",
                json_string(&self.benchmark),
                json_string(&row.case),
                json_string(&row.metric),
                if row.value.is_finite() { format!("{}", row.value) } else { "null".into() },
                json_string(&row.unit),
                row.threads,
                json_string(&row.note),
                if i + 1 < self.rows.len() { "," } else { "" }
            );
        }
        text += "]\n";
        let path = dir.join(format!("{}.json", self.benchmark));
        let mut file = std::fs::File::create(&path).expect("create result file");
        file.write_all(text.as_bytes()).expect("write result file");
        println!("wrote {}", path.display());
    }
}

fn json_string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out += "\\\"",
            '\\' => out += "\\\\",
            '\n' => out += "\\n",
            c if (c as u32) < 0x20 => out += &format!("\\u{:04x}", c as u32),
            c => out.push(c),
        }
    }
    out + "\""
}

/// `<workspace>/bench/results`, or `$TEGUMENT_BENCH_DIR`.
pub fn results_dir() -> PathBuf {
    if let Ok(dir) = std::env::var("TEGUMENT_BENCH_DIR") {
        return PathBuf::from(dir);
    }
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../bench/results")
}

/// Median wall time in milliseconds of `runs` calls of `f` after one warm-up.
pub fn median_ms(runs: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut times: Vec<f64> = (0..runs.max(1))
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(|a, b| a.partial_cmp(b).unwrap());
    times[times.len() / 2]
}

/// Runs `f` inside a rayon pool of `threads` threads.
pub fn with_threads<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
        .install(f)
}

/// The memory-bandwidth reference: milliseconds to read `read_bytes` and
/// write `write_bytes` once, streaming, with `threads` threads (median of 7
/// after a warm-up). A hot loop's time divided by this is how many "passes
/// over its data" it costs.
///
/// The written bytes are a read-modify-write stream (`x = x·a + b`, so they
/// are also read, as in a solver sweep that updates its positions in place);
/// the remaining `read_bytes − write_bytes` are a read-only stream summed into
/// eight independent accumulators (vectorisable, not latency-bound). Both
/// streams are split into the same number of chunks, one task each, so every
/// thread streams both at once, like a sweep over rows. Buffers are allocated
/// and touched before timing (no page faults in the figure).
pub fn bandwidth_reference_ms(read_bytes: usize, write_bytes: usize, threads: usize) -> f64 {
    use rayon::prelude::*;
    let rw_len = (write_bytes / 4).max(1);
    let ro_len = read_bytes.saturating_sub(write_bytes) / 4;
    let mut rw = vec![1.0f32; rw_len];
    let ro = vec![1.0f32; ro_len.max(1)];
    let chunks = (threads * 64).max(1);
    let rw_chunk = rw_len.div_ceil(chunks);
    // Chunk `i` of the read-only stream goes with chunk `i` of the written one.
    let ro_chunk = ro_len.div_ceil(rw_len.div_ceil(rw_chunk)).max(1);
    with_threads(threads, || {
        median_ms(7, || {
            let sum: f32 = rw
                .par_chunks_mut(rw_chunk)
                .enumerate()
                .map(|(i, w)| {
                    let r = &ro[(i * ro_chunk).min(ro_len)..((i + 1) * ro_chunk).min(ro_len)];
                    for x in w.iter_mut() {
                        *x = *x * 0.999 + 0.001;
                    }
                    let mut acc = [0.0f32; 8];
                    let mut it = r.chunks_exact(8);
                    for c in &mut it {
                        for k in 0..8 {
                            acc[k] += c[k];
                        }
                    }
                    acc.iter().sum::<f32>() + it.remainder().iter().sum::<f32>()
                })
                .sum();
            std::hint::black_box(sum);
            std::hint::black_box(&rw);
        })
    })
}

/// Short description of the machine for the report.
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("model name")).map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string()))
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    format!("{cpu}, {cores} cores")
}

/// A sequence bound to `input` with the default options, solving with the
/// add-on's default solver (Converge: accelerated, stopped at
/// `CONVERGE_TOLERANCE`) when `converge`, else with plain iterations.
pub fn bind_sequence(input: tegument_core::mesh::MeshInput<'_>, converge: bool) -> tegument_core::sequence::Sequence {
    let mut sequence = tegument_core::sequence::Sequence::bind(input, tegument_core::pyramid::DeformerOptions::default()).unwrap();
    if converge {
        sequence.deformer_mut().set_accelerated(true);
        sequence.deformer_mut().set_tolerance(Some(tegument_core::pyramid::CONVERGE_TOLERANCE)).unwrap();
    }
    sequence
}
