//! Replays a recorded bake with Self Collision through `Sequence::step`, in
//! the core, without Blender: per frame the CPU time of the step (both
//! threads, from `/proc/self/stat`: comparable on a loaded host, unlike the
//! wall-clock), its contacts, held vertices and intersections, and
//! `StepReport::self_work` (gatherings whole and around, the largest
//! candidate list, where the time went). For comparing two builds of the
//! self-collision passes on a real character (issue 30), old and new
//! binaries alternating.
//!
//! The recording is the add-on's own `step()` inputs of one Bake (rest
//! positions and polygons of the bind, every frame's world-space input, the
//! iterations, closeness and Self Collision settings); it is made by
//! `bench/record_self_replay.py` into a file outside the project tree:
//!
//! ```text
//! make extension
//! .venv/bin/python bench/record_self_replay.py dist/tegument-0.1.0-linux_x64.zip /tmp/me/character.replay
//! cargo run --release -p tegument-core --example self_replay -- /tmp/me/character.replay [frames]
//! ```
//!
//! (`frames`: replay only the first that many; a third argument `without`
//! replays the same frames without Self Collision, the step it is compared
//! with; `TEGUMENT_REPLAY_OUTPUT=<path>` writes every frame's result there,
//! f32 xyz frame after frame, for an independent measure such as
//! `demo/measures.py`'s spike.) The recording's layout, all
//! little-endian 32-bit: a header of 16 words (vertex, corner, polygon and
//! frame counts, iterations, Converge as 0/1, then as f32 the tolerance (NaN:
//! none) and closeness (NaN: the default), thickness, static and kinetic
//! friction, then as u32 the ignored rings and scale-safe as 0/1, three
//! unused words), the rest positions (f32 xyz), the corner vertices and the
//! polygon sizes (u32), then each frame's positions (f32 xyz).
use std::time::Instant;

use glam::Vec3;
use tegument_core::collide::SelfSettings;
use tegument_core::mesh::MeshInput;
use tegument_core::pyramid::{Closeness, DeformerOptions};
use tegument_core::sequence::{SelfOptions, Sequence, StepOptions};

#[path = "../benches/common/self_work.rs"]
mod self_work;
use self_work::{cpu_seconds, work_line};

/// What a recording holds.
struct Recording {
    rest: Vec<Vec3>,
    corners: Vec<i32>,
    sizes: Vec<i32>,
    frames: Vec<Vec<Vec3>>,
    iterations: usize,
    accelerated: bool,
    tolerance: Option<f32>,
    /// NaN: the default.
    closeness: f32,
    settings: SelfSettings,
    scale_safe: bool,
}

/// Reads the words of a recording in order.
struct Words<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Words<'_> {
    fn u32(&mut self) -> Result<u32, String> {
        let word = self.bytes.get(4 * self.at..4 * self.at + 4).ok_or_else(|| format!("the recording ends at word {}", self.at))?;
        self.at += 1;
        Ok(u32::from_le_bytes(word.try_into().expect("four bytes")))
    }

    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_bits(self.u32()?))
    }

    fn positions(&mut self, count: usize) -> Result<Vec<Vec3>, String> {
        (0..count).map(|_| Ok(Vec3::new(self.f32()?, self.f32()?, self.f32()?))).collect()
    }

    fn indices(&mut self, count: usize) -> Result<Vec<i32>, String> {
        (0..count).map(|_| Ok(self.u32()? as i32)).collect()
    }
}

impl Recording {
    fn read(path: &str) -> Result<Self, String> {
        let bytes = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
        let mut w = Words { bytes: &bytes, at: 0 };
        let (n, nc, np, nf) = (w.u32()? as usize, w.u32()? as usize, w.u32()? as usize, w.u32()? as usize);
        let (iterations, accelerated) = (w.u32()? as usize, w.u32()? != 0);
        let (tolerance, closeness) = (w.f32()?, w.f32()?);
        let (thickness, static_friction, kinetic_friction) = (w.f32()?, w.f32()?, w.f32()?);
        let (rings, scale_safe) = (w.u32()?, w.u32()? != 0);
        w.at = 16;
        let rest = w.positions(n)?;
        let corners = w.indices(nc)?;
        let sizes = w.indices(np)?;
        let frames = (0..nf).map(|_| w.positions(n)).collect::<Result<Vec<_>, _>>()?;
        if 4 * w.at != bytes.len() {
            return Err(format!("{path}: {} bytes left over after {nf} frames of {n} vertices", bytes.len() - 4 * w.at));
        }
        Ok(Recording {
            rest,
            corners,
            sizes,
            frames,
            iterations,
            accelerated,
            tolerance: (!tolerance.is_nan()).then_some(tolerance),
            closeness,
            settings: SelfSettings { thickness, static_friction, kinetic_friction, rings },
            scale_safe,
        })
    }
}

fn main() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let path = args.next().ok_or("usage: self_replay <recording> [frames [without]]")?;
    let only: Option<usize> = args.next().map(|s| s.parse().map_err(|e| format!("frames: {e}"))).transpose()?;
    let without = match args.next().as_deref() {
        None => false,
        Some("without") => true,
        Some(other) => return Err(format!("the third argument is `without` or nothing, not {other:?}")),
    };
    let r = Recording::read(&path)?;
    println!(
        "{} vertices, {} polygons, {} frames, {} iterations, Converge {}, closeness {}, Distance {}, friction {}/{}, rings {}",
        r.rest.len(),
        r.sizes.len(),
        r.frames.len(),
        r.iterations,
        r.accelerated,
        r.closeness,
        r.settings.thickness,
        r.settings.static_friction,
        r.settings.kinetic_friction,
        r.settings.rings
    );
    let mesh = MeshInput { positions: &r.rest, corner_verts: &r.corners, polygon_sizes: &r.sizes };
    let mut sequence = Sequence::bind(mesh, DeformerOptions { scale_safe: r.scale_safe, ..DeformerOptions::default() }).map_err(|e| e.to_string())?;
    sequence.deformer_mut().set_accelerated(r.accelerated);
    sequence.deformer_mut().set_tolerance(r.tolerance).map_err(|e| e.to_string())?;
    let closeness = if r.closeness.is_nan() { Closeness::Default } else { Closeness::Uniform(r.closeness) };
    let self_collision = (!without).then_some(SelfOptions { settings: r.settings, weights: None });
    let options = StepOptions { self_collision, ..StepOptions::new(r.iterations, closeness) };
    let mut output = std::env::var_os("TEGUMENT_REPLAY_OUTPUT").map(std::fs::File::create).transpose().map_err(|e| format!("TEGUMENT_REPLAY_OUTPUT: {e}"))?;
    let (mut wall_total, mut cpu_total, mut held_total, mut contacts_total) = (0.0, 0.0, 0, 0);
    for (k, input) in r.frames.iter().enumerate().take(only.unwrap_or(usize::MAX)) {
        let (clock, cpu) = (Instant::now(), cpu_seconds());
        let (x, report) = sequence.step(input, &mut [], &options).map_err(|e| format!("frame {}: {e}", k + 1))?;
        if let Some(file) = output.as_mut() {
            let words: Vec<u8> = x.iter().flat_map(|p| p.to_array()).flat_map(f32::to_le_bytes).collect();
            std::io::Write::write_all(file, &words).map_err(|e| format!("TEGUMENT_REPLAY_OUTPUT: {e}"))?;
        }
        let wall = 1000.0 * clock.elapsed().as_secs_f64();
        let cpu = cpu.zip(cpu_seconds()).map_or(f64::NAN, |(a, b)| 1000.0 * (b - a));
        wall_total += wall;
        cpu_total += cpu;
        held_total += report.self_held;
        contacts_total += report.self_contacts;
        println!(
            "frame {}: {wall:.0} ms wall, {cpu:.0} ms cpu; contacts {}, held {}, intersections {}, tangled {}; {}",
            k + 1,
            report.self_contacts,
            report.self_held,
            report.self_intersections,
            report.self_tangled,
            work_line(&report.self_work)
        );
    }
    println!("total {wall_total:.0} ms wall, {cpu_total:.0} ms cpu; contacts {contacts_total}, held {held_total}");
    Ok(())
}
