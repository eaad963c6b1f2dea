//! What `glimpse render --stats` reports beside the render's own statistics: the time of
//! each phase of the command (load, build, render), the samples per second, and the
//! process's resident memory, so a scene's cost at scale can be compared with another
//! renderer's on the same file (benches/scenes_at_scale.rs).

use crate::progressive::RenderStats;
use serde::Serialize;

/// The phases of one `glimpse render`, in the order they run.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Phases {
    /// Reading, importing and validating the scene file (`import::load_path`).
    pub load_ms: f64,
    /// Preparing the tracer: BVH, light tables, materials (`PathTracer::new`).
    pub build_ms: f64,
    /// The render itself, from the first ray to the last frame (denoising included).
    pub render_ms: f64,
    /// Paths traced: `samples_traced` in adaptive mode, else pixels × samples per pixel.
    pub samples: u64,
    /// `samples` over `render_ms`.
    pub samples_per_second: f64,
    /// Primitives the tracer holds (triangles and spheres).
    pub primitives: u64,
    pub memory: Memory,
}

/// Resident memory of the process in bytes (Linux `/proc/self/status`; `None` where it
/// cannot be read).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Memory {
    /// Highest resident set of the whole command (`VmHWM`): the peak, usually in load or
    /// build.
    pub peak_bytes: Option<u64>,
    /// Highest resident set by the end of the load (`VmHWM` then): the import's peak.
    pub load_peak_bytes: Option<u64>,
    /// Resident once the scene is loaded (the imported document freed): what the
    /// validated scene costs.
    pub loaded_bytes: Option<u64>,
    /// Resident once the tracer is built and the scene's geometry released: what the
    /// scene costs while it renders.
    pub built_bytes: Option<u64>,
    /// Resident at the end, frame buffers included (`VmRSS`).
    pub final_bytes: Option<u64>,
}

/// The process's resident set now and its peak so far.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Resident {
    pub now_bytes: u64,
    pub peak_bytes: u64,
}

/// This process's [`Resident`] memory, if the system tells it.
#[must_use]
pub fn resident() -> Option<Resident> {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| parse_status(&s))
}

/// The memory this machine can give a new allocation without swapping (`MemAvailable`
/// of `/proc/meminfo`), `None` where that is not known.
#[must_use]
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    kib_field(&text, "MemAvailable:")
}

/// A `NAME:  1234 kB` line of a proc(5) file, in bytes.
fn kib_field(text: &str, name: &str) -> Option<u64> {
    text.lines()
        .find_map(|l| l.strip_prefix(name))
        .and_then(|rest| rest.trim().strip_suffix("kB"))
        .and_then(|n| n.trim().parse::<u64>().ok())
        .map(|kib| kib * 1024)
}

/// `VmRSS` and `VmHWM` of a `/proc/PID/status` text (proc(5): values in kB, i.e. KiB).
fn parse_status(text: &str) -> Option<Resident> {
    let field = |name: &str| kib_field(text, name);
    Some(Resident {
        now_bytes: field("VmRSS:")?,
        peak_bytes: field("VmHWM:")?,
    })
}

impl Phases {
    /// Paths traced by a render of `spp` samples per pixel that ended with `stats`.
    #[must_use]
    pub fn samples_of(stats: &RenderStats, spp: u32) -> u64 {
        if stats.samples_traced > 0 {
            stats.samples_traced
        } else {
            stats.pixels_traced * u64::from(spp)
        }
    }

    /// `samples` per second of `render_ms` (0 for an instant render).
    #[must_use]
    pub fn rate(samples: u64, render_ms: f64) -> f64 {
        if render_ms > 0.0 {
            samples as f64 / (render_ms / 1e3)
        } else {
            0.0
        }
    }
}

/// The `--stats` file: the render's statistics, unchanged, and the command's `phases`.
#[derive(Serialize)]
pub struct StatsFile<'a> {
    #[serde(flatten)]
    pub render: &'a RenderStats,
    pub phases: &'a Phases,
}

#[cfg(test)]
mod tests {
    use super::*;

    const STATUS: &str = "Name:\tglimpse\nVmPeak:\t  900000 kB\nVmHWM:\t  561392 kB\n\
                          VmRSS:\t  200000 kB\nThreads:\t3\n";

    #[test]
    fn resident_memory_is_read_from_proc_status_in_bytes() {
        assert_eq!(
            parse_status(STATUS),
            Some(Resident {
                now_bytes: 200_000 * 1024,
                peak_bytes: 561_392 * 1024
            })
        );
        assert_eq!(parse_status("Name:\tx\nVmRSS:\t12 kB\n"), None);
        assert_eq!(parse_status("VmRSS:\tlots kB\nVmHWM:\t1 kB\n"), None);
        assert_eq!(parse_status(""), None);
    }

    #[test]
    fn this_process_has_a_resident_set() {
        let r = resident().expect("Linux has /proc/self/status");
        assert!(r.now_bytes > 0 && r.peak_bytes >= r.now_bytes, "{r:?}");
    }

    #[test]
    fn samples_count_paths_and_the_rate_is_per_second() {
        let mut s = RenderStats {
            pixels_traced: 1000,
            ..RenderStats::default()
        };
        assert_eq!(Phases::samples_of(&s, 64), 64_000);
        s.samples_traced = 5000;
        assert_eq!(Phases::samples_of(&s, 64), 5000);
        assert_eq!(Phases::rate(64_000, 2000.0), 32_000.0);
        assert_eq!(Phases::rate(64_000, 0.0), 0.0);
    }

    #[test]
    fn the_stats_file_keeps_the_render_fields_at_the_top_level() {
        let s = RenderStats {
            width: 4,
            ..RenderStats::default()
        };
        let p = Phases {
            load_ms: 1.5,
            ..Phases::default()
        };
        let v = serde_json::to_value(StatsFile {
            render: &s,
            phases: &p,
        })
        .unwrap();
        assert_eq!(v["width"], 4);
        assert_eq!(v["phases"]["load_ms"], 1.5);
        assert!(v["phases"]["memory"]["peak_bytes"].is_null());
    }
}
