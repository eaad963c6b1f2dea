//! Where a `glimpse bench` run is: which scene, at which stage or viewing condition, how
//! many scenes are done of how many, the time so far and the time left at the pace so
//! far (scenes differ in cost, so it is "about"; none before the first scene is done).
//! On a terminal, one bar on stderr that redraws itself; otherwise (a log, CI) one plain
//! line per stage.

use crate::progressive::eta::seconds;
use indicatif::ProgressState;
use std::fmt::Write;
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::Instant;

/// A run's progress over `total` scenes.
pub struct Progress {
    bar: Option<indicatif::ProgressBar>,
    total: usize,
    start: Instant,
    /// Scenes finished, and the scene now running.
    state: Mutex<(usize, String)>,
}

impl Progress {
    /// A bar when stderr is a terminal, plain lines otherwise.
    #[must_use]
    pub fn new(total: usize) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = indicatif::ProgressBar::new(total as u64);
            if let Ok(style) = indicatif::ProgressStyle::with_template(
                "{spinner} [{bar:24}] {pos}/{len} scenes, {elapsed} so far{left}: {msg}",
            ) {
                let style = style.with_key("left", |s: &ProgressState, w: &mut dyn Write| {
                    let left = time_left(s.pos(), s.len(), s.elapsed().as_secs_f64());
                    let _ = w.write_str(&left);
                });
                bar.set_style(style.progress_chars("=> "));
            }
            bar.enable_steady_tick(std::time::Duration::from_millis(200));
            bar
        });
        Self {
            bar,
            total,
            start: Instant::now(),
            state: Mutex::new((0, String::new())),
        }
    }

    /// Scene `name` (with its size and samples in `about`) begins.
    pub fn scene(&self, name: &str, about: &str) {
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        st.1 = name.to_owned();
        let done = st.0;
        drop(st);
        self.say(done, &format!("{name} ({about})"));
    }

    /// The running scene enters `stage` ("the t0 sweep at 45 ppd").
    pub fn stage(&self, stage: &str) {
        let (done, name) = {
            let st = self.state.lock().unwrap_or_else(|e| e.into_inner());
            (st.0, st.1.clone())
        };
        self.say(done, &format!("{name}: {stage}"));
    }

    /// The running scene is finished.
    pub fn scene_done(&self) {
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        st.0 += 1;
        if let Some(bar) = &self.bar {
            bar.set_position(st.0 as u64);
        }
    }

    /// Text printed above the bar (a scene's table), or as it is without one.
    pub fn println(&self, text: &str) {
        match &self.bar {
            Some(bar) => bar.println(text),
            None => eprintln!("{text}"),
        }
    }

    /// Removes the bar at the end of the run.
    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }

    fn say(&self, done: usize, what: &str) {
        match &self.bar {
            Some(bar) => bar.set_message(what.to_owned()),
            None => eprintln!(
                "{}",
                line(done, self.total, what, self.start.elapsed().as_secs_f64())
            ),
        }
    }
}

/// A plain progress line: "bench: [2/5 scenes done, 1 min 3 s so far, about 1 min 35 s
/// left] cornell-box: at 45 ppd".
fn line(done: usize, total: usize, what: &str, elapsed_s: f64) -> String {
    format!(
        "bench: [{done}/{total} scenes done, {} so far{}] {what}",
        seconds(elapsed_s * 1e3),
        time_left(done as u64, Some(total as u64), elapsed_s)
    )
}

/// ", about 1 min left" at the mean pace of the scenes done; empty before the first is
/// done (nothing to go on) and once all are.
fn time_left(done: u64, total: Option<u64>, elapsed_s: f64) -> String {
    match total {
        Some(total) if done > 0 && done < total => {
            let left_s = elapsed_s / done as f64 * (total - done) as f64;
            format!(", about {} left", seconds(left_s * 1e3))
        }
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plain_line_says_where_and_how_long() {
        assert_eq!(
            line(2, 5, "cornell-box: at 45 ppd", 63.2),
            "bench: [2/5 scenes done, 1 min 3 s so far, about 1 min 35 s left] cornell-box: at 45 ppd"
        );
        assert_eq!(
            line(0, 13, "door (256x256, 64 spp)", 0.4),
            "bench: [0/13 scenes done, 400 ms so far] door (256x256, 64 spp)"
        );
        assert_eq!(
            line(3, 3, "done", 10.0),
            "bench: [3/3 scenes done, 10.0 s so far] done"
        );
        // The bar's own key: a bar of unknown length has no time left to give.
        assert_eq!(time_left(1, None, 5.0), "");
        assert_eq!(time_left(1, Some(3), 5.0), ", about 10.0 s left");
    }

    #[test]
    fn counts_scenes_as_they_finish() {
        let p = Progress::new(3);
        p.scene("a", "8x8, 1 spp");
        p.stage("truth");
        p.scene_done();
        p.scene("b", "8x8, 1 spp");
        let st = p.state.lock().unwrap();
        assert_eq!((st.0, st.1.as_str()), (1, "b"));
    }
}
